//! `millgate registers`: the register map as Markdown, CSV or JSON, from the same
//! table the gateway encodes with ([`crate::outputs::register_map`]).

use millgate_config::{ValueType, WordOrder};
use serde::Serialize;

use crate::outputs::register_map::RegisterMap;

/// Output format of the export.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// A Markdown table (the README's).
    Md,
    /// CSV with a header line.
    Csv,
    /// A JSON array of registers.
    Json,
}

#[derive(Serialize)]
struct Row<'a> {
    name: &'a str,
    address: u16,
    #[serde(rename = "type")]
    value_type: &'static str,
    scale: f64,
    word_order: &'static str,
    unit: &'a str,
    access: &'static str,
    description: &'a str,
}

/// `u16`, `i16`, ... as written in configurations and exports.
pub fn type_name(value_type: ValueType) -> &'static str {
    match value_type {
        ValueType::U16 => "u16",
        ValueType::I16 => "i16",
        ValueType::U32 => "u32",
        ValueType::I32 => "i32",
        ValueType::F32 => "f32",
    }
}

/// `ABCD`, `CDAB`, ...
pub fn word_order_name(order: WordOrder) -> &'static str {
    match order {
        WordOrder::Abcd => "ABCD",
        WordOrder::Cdab => "CDAB",
        WordOrder::Badc => "BADC",
        WordOrder::Dcba => "DCBA",
    }
}

fn rows(map: &RegisterMap) -> impl Iterator<Item = Row<'_>> {
    map.registers().iter().map(|r| Row {
        name: &r.name,
        address: r.address,
        value_type: type_name(r.value_type),
        scale: r.scale,
        word_order: word_order_name(r.word_order),
        unit: r.unit,
        access: r.access.code(),
        description: &r.description,
    })
}

/// `text` as one CSV field: quoted (quotes doubled) when it holds a comma, a quote or
/// a line break.
pub(crate) fn csv_field(text: &str) -> String {
    if text.contains([',', '"', '\n']) {
        format!("\"{}\"", text.replace('"', "\"\""))
    } else {
        text.to_owned()
    }
}

/// The map of `map` in `format`, addresses as offsets from the map's base.
pub fn export(map: &RegisterMap, format: Format) -> String {
    match format {
        Format::Json => {
            let rows: Vec<Row<'_>> = rows(map).collect();
            serde_json::to_string_pretty(&rows).unwrap_or_default() + "\n"
        }
        Format::Csv => {
            let mut out =
                String::from("name,address,type,scale,word_order,unit,access,description\n");
            for row in rows(map) {
                out += &format!(
                    "{},{},{},{},{},{},{},{}\n",
                    csv_field(row.name),
                    row.address,
                    row.value_type,
                    row.scale,
                    row.word_order,
                    csv_field(row.unit),
                    row.access,
                    csv_field(row.description)
                );
            }
            out
        }
        Format::Md => {
            let mut out = String::from(
                "| address | hex | name | type | unit | scale | word order | access | description |\n\
                 |---|---|---|---|---|---|---|---|---|\n",
            );
            for row in rows(map) {
                out += &format!(
                    "| {} | 0x{:04X} | {} | {} | {} | {} | {} | {} | {} |\n",
                    row.address,
                    row.address,
                    row.name,
                    row.value_type,
                    row.unit.replace('*', "\\*"),
                    row.scale,
                    row.word_order,
                    row.access,
                    row.description.replace('|', "\\|")
                );
            }
            out
        }
    }
}
