//! `millgate registers`: the register map as Markdown, CSV or JSON, from the same
//! table the gateway encodes with ([`crate::outputs::modbus::register_map`]).
//!
//! Addresses are Modbus PDU addresses, 0-based (the number in the request frame): the
//! map's own offsets, which the HMI server serves them at, and, with a PLC output, the
//! holding registers written in the PLC (`outputs.plc.register_base` + offset). A tool
//! that counts from 1 (the Modicon 4xxxx notation, mbpoll without `-0`) shows
//! address 0 as register 1 (40001).

use millgate_config::{PlcOutput, ValueType, WordOrder};
use serde::Serialize;

use crate::outputs::modbus::register_map::RegisterMap;

/// Output format of the export.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// A Markdown table (docs/register-map.md's).
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
    /// `register_base + address` in the PLC; `None` without a PLC output.
    plc_address: Option<u32>,
    #[serde(rename = "type")]
    value_type: &'static str,
    scale: f64,
    word_order: &'static str,
    unit: &'a str,
    access: &'static str,
    description: &'a str,
}

/// `u16`, `i16`, ... as written in configurations and exports.
pub(crate) fn type_name(value_type: ValueType) -> &'static str {
    match value_type {
        ValueType::U16 => "u16",
        ValueType::I16 => "i16",
        ValueType::U32 => "u32",
        ValueType::I32 => "i32",
        ValueType::F32 => "f32",
    }
}

/// `ABCD`, `CDAB`, ...
pub(crate) fn word_order_name(order: WordOrder) -> &'static str {
    match order {
        WordOrder::Abcd => "ABCD",
        WordOrder::Cdab => "CDAB",
        WordOrder::Badc => "BADC",
        WordOrder::Dcba => "DCBA",
    }
}

fn rows<'a>(map: &'a RegisterMap, plc: Option<&PlcOutput>) -> impl Iterator<Item = Row<'a>> {
    let written = plc.map(|plc| (plc.register_base, map.plc_span(plc.extension_blocks)));
    map.registers().iter().map(move |r| Row {
        name: &r.name,
        address: r.address,
        plc_address: written
            .filter(|(_, span)| r.address < *span)
            .map(|(base, _)| u32::from(base) + u32::from(r.address)),
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

/// The map of `map` in `format`: each register's offset from the map's start (the
/// HMI server's address) and, with `plc` (`[outputs.plc]`), its address in the PLC
/// (`register_base` + offset; none for an extension block the PLC is not written);
/// both 0-based PDU addresses.
pub fn export(map: &RegisterMap, output: Option<&PlcOutput>, format: Format) -> String {
    let plc = |row: &Row<'_>| row.plc_address.map_or(String::new(), |a| a.to_string());
    match format {
        Format::Json => {
            let rows: Vec<Row<'_>> = rows(map, output).collect();
            serde_json::to_string_pretty(&rows).unwrap_or_default() + "\n"
        }
        Format::Csv => {
            let mut out = String::from(
                "name,address,plc_address,type,scale,word_order,unit,access,description\n",
            );
            for row in rows(map, output) {
                out += &format!(
                    "{},{},{},{},{},{},{},{},{}\n",
                    csv_field(row.name),
                    row.address,
                    plc(&row),
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
                "| address | hex | PLC address | name | type | unit | scale | word order | access | description |\n\
                 |---|---|---|---|---|---|---|---|---|---|\n",
            );
            for row in rows(map, output) {
                out += &format!(
                    "| {} | 0x{:04X} | {} | {} | {} | {} | {} | {} | {} | {} |\n",
                    row.address,
                    row.address,
                    row.plc_address.map_or("-".to_owned(), |a| a.to_string()),
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
