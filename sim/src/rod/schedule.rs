//! The rolling schedule: one CSV row per pass.
//!
//! ```text
//! pass,configuration,finishing_speed_m_s,temperature_c,diameters_mm
//! # comment lines start with '#'
//! P1,table3,80.0,950,16.0;13.5;10.5;9.0
//! ```
//!
//! - `pass`: a name; `configuration`: one of the drive's (or `default`);
//! - `finishing_speed_m_s`: rod speed out of the finishing stand, m/s, > 0; or leave it
//!   empty and give `stand_speeds_m_s` (optional column): the rod speed out of every
//!   stand, `;`-separated in rolling order;
//! - `temperature_c`: rod temperature, deg C, within the mill's modulus table;
//! - `diameters_mm`: rod diameter out of every stand, mm, `;`-separated in rolling
//!   order (the span after a stand carries its exit section). Without per-stand speeds
//!   the rod speeds follow from mass flow: `V_i = V_fin (d_fin / d_i)^2`.
//!
//! Fields are separated by commas and not quoted (names hold no commas). Errors name
//! the file, the line and the column.

use std::path::Path;

use super::RodError;
use crate::model::read_text;

/// One pass of the schedule, as given (validated against the mill by
/// [`super::check::PassSetup::new`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Pass {
    /// Pass name.
    pub name: String,
    /// Drive configuration name.
    pub configuration: String,
    /// Rod temperature, deg C.
    pub temperature_c: f64,
    /// Rod diameter out of each stand, m, in rolling order.
    pub diameters_m: Vec<f64>,
    /// Rod speed out of the finishing stand, m/s (`None` when `stand_speeds_m_s` is
    /// given: then the last of those).
    pub finishing_speed_m_s: Option<f64>,
    /// Rod speed out of each stand, m/s, when given instead of mass flow.
    pub stand_speeds_m_s: Option<Vec<f64>>,
    /// Where the pass comes from, for messages (`passes.csv:3`).
    pub origin: String,
}

const REQUIRED: [&str; 4] = ["pass", "configuration", "temperature_c", "diameters_mm"];
const OPTIONAL: [&str; 2] = ["finishing_speed_m_s", "stand_speeds_m_s"];

/// Reads a schedule CSV file; errors name the path as given.
pub fn load(path: impl AsRef<Path>) -> Result<Vec<Pass>, RodError> {
    let (text, file) = read_text(path.as_ref())?;
    parse(&text, &file)
}

/// Parses schedule CSV text; `file` labels errors.
pub(crate) fn parse(text: &str, file: &str) -> Result<Vec<Pass>, RodError> {
    let mut rows = text
        .lines()
        .enumerate()
        .map(|(index, line)| (index + 1, line.trim()))
        .filter(|(_, line)| !line.is_empty() && !line.starts_with('#'));
    let Some((header_line, header)) = rows.next() else {
        return Err(schedule_error(
            file,
            1,
            "(header)",
            "the file has no header row".to_owned(),
        ));
    };
    let columns = header_columns(file, header_line, header)?;
    let passes = rows
        .map(|(line, row)| Row::new(file, line, row, &columns)?.pass())
        .collect::<Result<Vec<Pass>, RodError>>()?;
    if passes.is_empty() {
        return Err(schedule_error(
            file,
            header_line,
            "(row)",
            "the schedule has no pass".to_owned(),
        ));
    }
    Ok(passes)
}

/// The error at `line` of `file`, for `key`.
fn schedule_error(file: &str, line: usize, key: &str, message: String) -> RodError {
    RodError::Schedule {
        file: file.to_owned(),
        line,
        key: key.to_owned(),
        message,
    }
}

/// The header's columns: each known and once, every required one, and a speed
/// column.
fn header_columns<'a>(
    file: &str,
    header_line: usize,
    header: &'a str,
) -> Result<Vec<&'a str>, RodError> {
    let error = |message: String| schedule_error(file, header_line, "(header)", message);
    let columns: Vec<&str> = header.split(',').map(str::trim).collect();
    for (index, column) in columns.iter().enumerate() {
        if !REQUIRED.contains(column) && !OPTIONAL.contains(column) {
            return Err(error(format!(
                "unknown column {column:?} (allowed: {}, {})",
                REQUIRED.join(", "),
                OPTIONAL.join(", ")
            )));
        }
        if columns[..index].contains(column) {
            return Err(error(format!("column {column:?} twice")));
        }
    }
    for required in REQUIRED {
        if !columns.contains(&required) {
            return Err(error(format!("missing column {required:?}")));
        }
    }
    if !OPTIONAL.iter().any(|c| columns.contains(c)) {
        return Err(error(
            "needs finishing_speed_m_s or stand_speeds_m_s".to_owned(),
        ));
    }
    Ok(columns)
}

/// One data row: its fields under the header's columns.
struct Row<'a> {
    file: &'a str,
    line: usize,
    columns: &'a [&'a str],
    fields: Vec<&'a str>,
}

impl<'a> Row<'a> {
    /// The fields of `row` at `line`, one per column.
    fn new(
        file: &'a str,
        line: usize,
        row: &'a str,
        columns: &'a [&'a str],
    ) -> Result<Row<'a>, RodError> {
        let fields: Vec<&str> = row.split(',').map(str::trim).collect();
        if fields.len() != columns.len() {
            return Err(schedule_error(
                file,
                line,
                "(row)",
                format!("{} fields, the header has {}", fields.len(), columns.len()),
            ));
        }
        Ok(Row {
            file,
            line,
            columns,
            fields,
        })
    }

    /// The pass of this row.
    fn pass(&self) -> Result<Pass, RodError> {
        let name = self.required("pass")?.to_owned();
        let configuration = self.required("configuration")?.to_owned();
        let temperature_c =
            self.number("temperature_c", self.required("temperature_c")?, "deg C")?;
        let diameters_m = self
            .list("diameters_mm", self.required("diameters_mm")?, "mm")?
            .into_iter()
            .map(|mm| mm / 1.0e3)
            .collect();
        let finishing_speed_m_s = self
            .field("finishing_speed_m_s")
            .map(|text| {
                self.positive(
                    "finishing_speed_m_s",
                    self.number("finishing_speed_m_s", text, "m/s")?,
                    "m/s",
                )
            })
            .transpose()?;
        let stand_speeds_m_s = self
            .field("stand_speeds_m_s")
            .map(|text| self.list("stand_speeds_m_s", text, "m/s"))
            .transpose()?;
        if finishing_speed_m_s.is_some() == stand_speeds_m_s.is_some() {
            return Err(self.error(
                "finishing_speed_m_s",
                "give either finishing_speed_m_s or stand_speeds_m_s (exactly one)".to_owned(),
            ));
        }
        Ok(Pass {
            name,
            configuration,
            temperature_c,
            diameters_m,
            finishing_speed_m_s,
            stand_speeds_m_s,
            origin: format!("{}:{}", self.file, self.line),
        })
    }

    fn error(&self, key: &str, message: String) -> RodError {
        schedule_error(self.file, self.line, key, message)
    }

    /// The field of column `name`, `None` when there is no such column or it is empty.
    fn field(&self, name: &str) -> Option<&'a str> {
        self.columns
            .iter()
            .position(|c| *c == name)
            .map(|i| self.fields[i])
            .filter(|f| !f.is_empty())
    }

    /// The field of column `name`, which must not be empty.
    fn required(&self, name: &str) -> Result<&'a str, RodError> {
        self.field(name)
            .ok_or_else(|| self.error(name, "empty".to_owned()))
    }

    /// `text` as a finite number (in `unit`).
    fn number(&self, name: &str, text: &str, unit: &str) -> Result<f64, RodError> {
        text.parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| self.error(name, format!("{text:?} is not a number ({unit})")))
    }

    /// `value` when > 0.
    fn positive(&self, name: &str, value: f64, unit: &str) -> Result<f64, RodError> {
        if value > 0.0 {
            Ok(value)
        } else {
            Err(self.error(name, format!("{value} is not allowed (must be > 0 {unit})")))
        }
    }

    /// `text` as `;`-separated positive numbers.
    fn list(&self, name: &str, text: &str, unit: &str) -> Result<Vec<f64>, RodError> {
        text.split(';')
            .map(|item| self.positive(name, self.number(name, item.trim(), unit)?, unit))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn message(text: &str) -> String {
        parse(text, "passes.csv").unwrap_err().to_string()
    }

    #[test]
    fn rows_parse_with_comments_and_either_speed_form() {
        let passes = parse(
            "# schedule\npass,configuration,finishing_speed_m_s,stand_speeds_m_s,temperature_c,diameters_mm\n\
             P1,table3,80,,950,16;13.5;10.5;9\n\n# next\nP2,fast,,20;30;50;70,900,16;13;10;8.5\n",
            "passes.csv",
        )
        .unwrap();
        assert_eq!(passes.len(), 2);
        assert_eq!(passes[0].finishing_speed_m_s, Some(80.0));
        assert_eq!(passes[0].diameters_m, vec![0.016, 0.0135, 0.0105, 0.009]);
        assert_eq!(passes[0].origin, "passes.csv:3");
        assert_eq!(
            passes[1].stand_speeds_m_s,
            Some(vec![20.0, 30.0, 50.0, 70.0])
        );
        assert_eq!(passes[1].origin, "passes.csv:6");
    }

    #[test]
    fn bad_rows_name_line_column_and_range() {
        let header = "pass,configuration,finishing_speed_m_s,temperature_c,diameters_mm\n";
        assert_eq!(
            message(&format!("{header}P1,table3,80,950,16;-13.5;10\n")),
            "passes.csv:2: diameters_mm: -13.5 is not allowed (must be > 0 mm)"
        );
        assert_eq!(
            message(&format!("{header}P1,table3,0,950,16;13.5\n")),
            "passes.csv:2: finishing_speed_m_s: 0 is not allowed (must be > 0 m/s)"
        );
        assert_eq!(
            message(&format!("{header}P1,table3,80,hot,16\n")),
            "passes.csv:2: temperature_c: \"hot\" is not a number (deg C)"
        );
        assert_eq!(
            message(&format!("{header}P1,table3,80,950\n")),
            "passes.csv:2: (row): 4 fields, the header has 5"
        );
        assert!(message("pass,configuration,temperature_c,diameters_mm\n")
            .contains("needs finishing_speed_m_s or stand_speeds_m_s"));
        assert!(message("pass,config,speed\n").contains("unknown column \"config\""));
        assert!(message(header).contains("no pass"));
    }
}
