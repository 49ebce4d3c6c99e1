//! TOML text to [`RawConfig`]: the syntax pass and the schema pass.
//!
//! Both passes report every problem they find, not only the first:
//! - syntax: the TOML parser recovers after an error and lists them all, each as
//!   `line L, column C: <toml's message>`;
//! - schema: each list element (`channels[2]`, `sources.modbus[0]`, ...) is
//!   deserialized on its own, so a misspelt key in one channel does not hide one in
//!   another. The key path of an error is found by locating the error's span in the
//!   parsed document, and the message ends with the line and column.

use serde::de::DeserializeOwned;
use toml::de::{DeString, DeTable, DeValue, ValueDeserializer};
use toml::Spanned;

use crate::error::{line_column, Report};
use crate::raw::RawConfig;

/// Keys allowed at the top level of a configuration file.
const TOP_LEVEL_KEYS: [&str; 12] = [
    "name",
    "sources",
    "channels",
    "drivelines",
    "tandem_mills",
    "rod_mills",
    "outputs",
    "history",
    "cache_dir",
    "log_format",
    "gateway",
    "analysis",
];

/// Keys allowed in the `[sources]` table.
const SOURCE_KEYS: [&str; 2] = ["modbus", "can"];

/// Parses `text` into a [`RawConfig`]; `None` when any problem was reported.
pub(crate) fn parse(text: &str, report: &mut Report) -> Option<RawConfig> {
    let (root, syntax_errors) = DeTable::parse_recoverable(text);
    if !syntax_errors.is_empty() {
        for error in &syntax_errors {
            let (line, column) = line_column(text, error.span().map_or(0, |span| span.start));
            report.push(format!("line {line}, column {column}"), error.message());
        }
        return None;
    }
    let mut schema = Schema { text, report };
    let mut raw = RawConfig::default();
    let mut has_name = false;
    for (key, value) in root.get_ref() {
        match key.get_ref().as_ref() {
            "name" => {
                has_name = true;
                if let Some(name) = schema.value(value, "name") {
                    raw.name = name;
                }
            }
            "cache_dir" => raw.cache_dir = schema.value(value, "cache_dir"),
            "log_format" => raw.log_format = schema.value(value, "log_format"),
            "gateway" => raw.gateway = schema.value(value, "gateway").unwrap_or_default(),
            "analysis" => raw.analysis = schema.value(value, "analysis").unwrap_or_default(),
            "sources" => schema.sources(value, &mut raw),
            "channels" => raw.channels = schema.list(value, "channels"),
            "drivelines" => raw.drivelines = schema.list(value, "drivelines"),
            "tandem_mills" => raw.tandem_mills = schema.list(value, "tandem_mills"),
            "rod_mills" => raw.rod_mills = schema.list(value, "rod_mills"),
            "outputs" => raw.outputs = schema.value(value, "outputs").unwrap_or_default(),
            "history" => raw.history = schema.value(value, "history"),
            _ => schema.unknown_key(key, "", &TOP_LEVEL_KEYS),
        }
    }
    if !has_name {
        schema.report.push(
            "name",
            "missing (the plant or mill name, e.g. name = \"F1 hot strip mill\")",
        );
    }
    schema.report.is_empty().then_some(raw)
}

/// State of the schema pass: the document text (for positions) and the report.
struct Schema<'t, 'r> {
    text: &'t str,
    report: &'r mut Report,
}

impl Schema<'_, '_> {
    /// `[sources]`: a table of `modbus` and `can` lists.
    fn sources(&mut self, value: &Spanned<DeValue<'_>>, raw: &mut RawConfig) {
        let DeValue::Table(table) = value.get_ref() else {
            self.push_at(
                "sources",
                value.span().start,
                "must be a table holding [[sources.modbus]] and [[sources.can]] lists",
            );
            return;
        };
        for (key, value) in table {
            match key.get_ref().as_ref() {
                "modbus" => raw.modbus_sources = self.list(value, "sources.modbus"),
                "can" => raw.can_sources = self.list(value, "sources.can"),
                _ => self.unknown_key(key, "sources.", &SOURCE_KEYS),
            }
        }
    }

    /// Deserializes each element of the list at `key`; failed elements are reported
    /// and left out.
    fn list<T: DeserializeOwned>(&mut self, value: &Spanned<DeValue<'_>>, key: &str) -> Vec<T> {
        let DeValue::Array(elements) = value.get_ref() else {
            self.push_at(
                key,
                value.span().start,
                &format!("must be a list of tables, written [[{key}]]"),
            );
            return Vec::new();
        };
        elements
            .iter()
            .enumerate()
            .filter_map(|(index, element)| self.value(element, &format!("{key}[{index}]")))
            .collect()
    }

    /// Deserializes one value found at `key`.
    fn value<T: DeserializeOwned>(&mut self, value: &Spanned<DeValue<'_>>, key: &str) -> Option<T> {
        match T::deserialize(ValueDeserializer::from(value.clone())) {
            Ok(parsed) => Some(parsed),
            Err(error) => {
                let offset = error.span().map_or(value.span().start, |span| span.start);
                let inner = path_to(value.get_ref(), offset).unwrap_or_default();
                self.push_at(&format!("{key}{inner}"), offset, error.message());
                None
            }
        }
    }

    fn unknown_key(&mut self, key: &Spanned<DeString<'_>>, prefix: &str, allowed: &[&str]) {
        self.push_at(
            &format!("{prefix}{}", key.get_ref()),
            key.span().start,
            &format!("unknown key (allowed here: {})", allowed.join(", ")),
        );
    }

    /// Records `message` at `key`, followed by the position of byte `offset`.
    fn push_at(&mut self, key: &str, offset: usize, message: &str) {
        let (line, column) = line_column(self.text, offset);
        self.report
            .push(key, format!("{message} (line {line}, column {column})"));
    }
}

/// Key path (`.source.blok`, `[1]`) from `value` down to the key or value whose span
/// holds byte `offset`; `None` when nothing below `value` holds it.
fn path_to(value: &DeValue<'_>, offset: usize) -> Option<String> {
    let holds = |span: core::ops::Range<usize>| span.contains(&offset) || span.start == offset;
    match value {
        DeValue::Table(table) => table.iter().find_map(|(key, child)| {
            let name = key.get_ref();
            if holds(key.span()) {
                Some(format!(".{name}"))
            } else if let Some(rest) = path_to(child.get_ref(), offset) {
                Some(format!(".{name}{rest}"))
            } else {
                holds(child.span()).then(|| format!(".{name}"))
            }
        }),
        DeValue::Array(elements) => elements.iter().enumerate().find_map(|(index, child)| {
            if let Some(rest) = path_to(child.get_ref(), offset) {
                Some(format!("[{index}]{rest}"))
            } else {
                holds(child.span()).then(|| format!("[{index}]"))
            }
        }),
        _ => None,
    }
}
