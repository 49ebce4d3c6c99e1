//! `millgate registers`: the register map as Markdown, CSV or JSON, from the same
//! table the gateway encodes with ([`crate::outputs::modbus::register_map`]).
//!
//! Addresses are Modbus PDU addresses, 0-based (the number in the request frame): the
//! map's own offsets, which the HMI server serves them at, and, with a PLC output, the
//! holding registers written in the PLC (`outputs.plc.register_base` + offset). A tool
//! that counts from 1 (the Modicon 4xxxx notation, mbpoll without `-0`) shows
//! address 0 as register 1 (40001).

use millgate_config::{ChannelSource, Config, ContextTags, PlcOutput, ValueType, WordOrder};
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

/// One context tag the gateway reads: what the PLC must provide.
#[derive(Serialize)]
struct ContextInput<'a> {
    /// The mill or driveline whose tag it is.
    subject: &'a str,
    /// `weld`, `weld_stands[0]`, `speed_mpm`, ... (the `context` table's key).
    tag: String,
    /// The `process_value` channel.
    channel: &'a str,
    /// The source (a `[[sources.modbus]]` or `[[sources.can]]` name).
    source: &'a str,
    /// `input`, `holding` or `can`.
    table: &'static str,
    /// First register (Modbus, 0-based PDU address); `None` for CAN.
    address: Option<u16>,
    /// The register type, or the CAN message and signal.
    encoding: String,
    /// The values the PLC may give (anything else makes the context invalid).
    allowed: String,
}

/// The values a context tag may take (`products`: the known product codes).
fn allowed(tag: &str, products: &[u32]) -> String {
    match tag {
        "weld" => "0 or 1 (1 while a weld is in the mill)".to_owned(),
        _ if tag.starts_with("weld_stands") => "0 or 1 (1 while a weld is in the stand)".to_owned(),
        "speed_mpm" => ">= 0 m/min".to_owned(),
        "thickness_mm" => "> 0 mm".to_owned(),
        "state" => "0 idle, 1 threading, 2 rolling, 3 maintenance".to_owned(),
        "product" if !products.is_empty() => {
            let codes: Vec<String> = products.iter().map(u32::to_string).collect();
            format!("one of {}", codes.join(", "))
        }
        _ => "a whole number 0..=4294967295".to_owned(),
    }
}

/// Every context tag of `config` (the tandem mills', then the drivelines'), with where
/// the gateway reads it and the values it accepts.
fn context_inputs(config: &Config) -> Vec<ContextInput<'_>> {
    let subjects = config
        .tandem_mills
        .iter()
        .map(|mill| (mill.name.as_str(), &mill.context))
        .chain(
            config
                .drivelines
                .iter()
                .map(|driveline| (driveline.name.as_str(), &driveline.context)),
        );
    let mut inputs = Vec::new();
    for (subject, tags) in subjects {
        let tags: &ContextTags = tags;
        let weld_stands = tags
            .weld_stands
            .iter()
            .enumerate()
            .map(|(stand, &channel)| (format!("weld_stands[{stand}]"), channel));
        let all = tags
            .tags()
            .map(|(tag, channel)| (tag.to_owned(), channel))
            .chain(weld_stands);
        for (tag, channel) in all {
            let channel = &config.channels[channel];
            let (source, table, address, encoding) = match &channel.source {
                ChannelSource::ModbusValue {
                    source,
                    table,
                    address,
                    value_type,
                    word_order,
                } => (
                    config.modbus_sources[*source].name.as_str(),
                    table.name(),
                    Some(*address),
                    format!(
                        "{} {}, x {} + {}",
                        type_name(*value_type),
                        word_order_name(*word_order),
                        channel.scale,
                        channel.offset
                    ),
                ),
                ChannelSource::ModbusText {
                    source,
                    table,
                    address,
                    registers,
                    byte_order,
                } => (
                    config.modbus_sources[*source].name.as_str(),
                    table.name(),
                    Some(*address),
                    format!("ascii, {registers} registers, {}", byte_order.name()),
                ),
                ChannelSource::Can {
                    source,
                    message,
                    signal,
                    ..
                } => (
                    config.can_sources[*source].name.as_str(),
                    "can",
                    None,
                    format!("{message}.{signal}"),
                ),
                // A context tag is a process value: never a block (the configuration
                // refuses it).
                ChannelSource::ModbusBlock { .. } => continue,
            };
            let allowed = match channel.source {
                ChannelSource::ModbusText { registers, .. } => format!(
                    "1..={} printable ASCII characters (0x20..=0x7E), ended by a NUL or padded \
                     with spaces",
                    2 * registers
                ),
                _ => allowed(&tag, &tags.products),
            };
            inputs.push(ContextInput {
                subject,
                allowed,
                tag,
                channel: &channel.name,
                source,
                table,
                address,
                encoding,
            });
        }
    }
    inputs
}

/// What the PLC must provide for `config`'s process-context tags (`registers
/// --context`), in `format`: per tag its subject, channel, source, table, address,
/// encoding and the values the gateway accepts.
pub fn context_export(config: &Config, format: Format) -> String {
    let inputs = context_inputs(config);
    let address = |input: &ContextInput<'_>| input.address.map_or(String::new(), |a| a.to_string());
    match format {
        Format::Json => serde_json::to_string_pretty(&inputs).unwrap_or_default() + "\n",
        Format::Csv => {
            let mut out =
                String::from("subject,tag,channel,source,table,address,encoding,allowed\n");
            for input in &inputs {
                out += &format!(
                    "{},{},{},{},{},{},{},{}\n",
                    csv_field(input.subject),
                    input.tag,
                    csv_field(input.channel),
                    csv_field(input.source),
                    input.table,
                    address(input),
                    csv_field(&input.encoding),
                    csv_field(&input.allowed)
                );
            }
            out
        }
        Format::Md => {
            let mut out = String::from(
                "| subject | tag | channel | source | table | address | encoding | allowed |\n\
                 |---|---|---|---|---|---|---|---|\n",
            );
            for input in &inputs {
                out += &format!(
                    "| {} | {} | {} | {} | {} | {} | {} | {} |\n",
                    input.subject,
                    input.tag,
                    input.channel,
                    input.source,
                    input.table,
                    input.address.map_or("-".to_owned(), |a| a.to_string()),
                    input.encoding,
                    input.allowed
                );
            }
            out
        }
    }
}
