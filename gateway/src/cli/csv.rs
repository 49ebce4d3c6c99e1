//! Reader of recorded signals: a CSV with a header, first column `t` (s), the other
//! columns channels (torque in kN*m). Errors name the line (1-based) and the column.

use std::path::Path;

/// A CSV that cannot be used; every variant names where.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum CsvError {
    /// The file has no header line.
    #[error("line 1: empty file, expected a header `t,<channel>,...`")]
    Empty,
    /// The first header cell is not `t`.
    #[error("line 1, column 1: expected `t` (time in s), found `{found}`")]
    TimeColumn {
        /// The first header cell.
        found: String,
    },
    /// The header names no channel.
    #[error("line 1: no channel column after `t`")]
    NoChannel,
    /// A data row has fewer cells than the header.
    #[error("line {line}, column {column} (`{name}`): missing value")]
    MissingColumn {
        /// 1-based line number.
        line: usize,
        /// 1-based column number.
        column: usize,
        /// Header name of the column.
        name: String,
    },
    /// A data row has more cells than the header.
    #[error(
        "line {line}, column {column}: unexpected extra value (header has {expected} columns)"
    )]
    ExtraColumn {
        /// 1-based line number.
        line: usize,
        /// 1-based column number of the first extra cell.
        column: usize,
        /// Number of header columns.
        expected: usize,
    },
    /// A cell is not a finite number.
    #[error("line {line}, column {column} (`{name}`): `{value}` is not a finite number")]
    NonNumeric {
        /// 1-based line number.
        line: usize,
        /// 1-based column number.
        column: usize,
        /// Header name of the column.
        name: String,
        /// The cell text.
        value: String,
    },
    /// Time does not strictly increase.
    #[error(
        "line {line}, column 1 (`t`): time {time_s} s is not after the previous {previous_s} s"
    )]
    NonMonotonicTime {
        /// 1-based line number.
        line: usize,
        /// Time on this line, s.
        time_s: f64,
        /// Time on the previous data line, s.
        previous_s: f64,
    },
    /// Fewer than two data rows: no sample rate.
    #[error("fewer than two data lines: the sample rate is undefined")]
    TooShort,
    /// The file could not be read.
    #[error("cannot read {path}: {message}")]
    Io {
        /// The file.
        path: String,
        /// The I/O error text.
        message: String,
    },
}

/// A parsed record: time column and channels, column-major.
#[derive(Debug, Clone, PartialEq)]
pub struct Table {
    /// Channel names from the header, in order (without `t`).
    pub names: Vec<String>,
    /// Time of each row, s, strictly increasing.
    pub time_s: Vec<f64>,
    /// One vector per channel, same length as `time_s`.
    pub channels: Vec<Vec<f64>>,
}

impl Table {
    /// Mean sample rate, Hz: (rows - 1) / (last time - first time).
    pub fn sample_rate_hz(&self) -> f64 {
        let n = self.time_s.len();
        (n - 1) as f64 / (self.time_s[n - 1] - self.time_s[0])
    }

    /// The channel called `name`, if any.
    pub fn channel(&self, name: &str) -> Option<&[f64]> {
        self.names
            .iter()
            .position(|n| n == name)
            .map(|i| self.channels[i].as_slice())
    }

    /// The channel called `name`, or the first one after `t` when `name` is `None`;
    /// the error names the header line and the channels there are.
    pub fn pick<'a>(&'a self, name: Option<&'a str>) -> Result<(&'a str, &'a [f64]), String> {
        match name {
            Some(name) => self
                .channel(name)
                .map(|values| (name, values))
                .ok_or_else(|| {
                    format!(
                        "line 1: no column `{name}` (channels: {})",
                        self.names.join(", ")
                    )
                }),
            None => Ok((self.names[0].as_str(), self.channels[0].as_slice())),
        }
    }
}

/// Reads and parses the CSV at `path`.
pub fn read(path: &Path) -> Result<Table, CsvError> {
    let text = std::fs::read_to_string(path).map_err(|e| CsvError::Io {
        path: path.display().to_string(),
        message: e.to_string(),
    })?;
    parse(&text)
}

/// Parses CSV text (comma-separated, cells trimmed, blank lines skipped).
pub fn parse(text: &str) -> Result<Table, CsvError> {
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty());
    let (_, header) = lines.next().ok_or(CsvError::Empty)?;
    let header: Vec<String> = header.split(',').map(|c| c.trim().to_string()).collect();
    if header[0] != "t" {
        return Err(CsvError::TimeColumn {
            found: header[0].clone(),
        });
    }
    if header.len() < 2 {
        return Err(CsvError::NoChannel);
    }
    let mut table = Table {
        names: header[1..].to_vec(),
        time_s: Vec::new(),
        channels: vec![Vec::new(); header.len() - 1],
    };
    for (line, row) in lines {
        let cells: Vec<&str> = row.split(',').map(str::trim).collect();
        if cells.len() > header.len() {
            return Err(CsvError::ExtraColumn {
                line,
                column: header.len() + 1,
                expected: header.len(),
            });
        }
        for (index, name) in header.iter().enumerate() {
            let column = index + 1;
            let cell = match cells.get(index) {
                Some(cell) if !cell.is_empty() => *cell,
                _ => {
                    return Err(CsvError::MissingColumn {
                        line,
                        column,
                        name: name.clone(),
                    })
                }
            };
            let value = cell
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| CsvError::NonNumeric {
                    line,
                    column,
                    name: name.clone(),
                    value: cell.to_string(),
                })?;
            if index == 0 {
                if let Some(&previous_s) = table.time_s.last() {
                    if value <= previous_s {
                        return Err(CsvError::NonMonotonicTime {
                            line,
                            time_s: value,
                            previous_s,
                        });
                    }
                }
                table.time_s.push(value);
            } else {
                table.channels[index - 1].push(value);
            }
        }
    }
    if table.time_s.len() < 2 {
        return Err(CsvError::TooShort);
    }
    Ok(table)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_header_and_columns() {
        let table = parse("t, a ,b\n0,1,2\n\n0.5,3,4\n").unwrap();
        assert_eq!(table.names, ["a", "b"]);
        assert_eq!(table.time_s, [0.0, 0.5]);
        assert_eq!(table.channel("b"), Some(&[2.0, 4.0][..]));
        assert_eq!(table.sample_rate_hz(), 2.0);
    }

    #[test]
    fn errors_name_line_and_column() {
        assert_eq!(
            parse("t,a\n0,1\n0.1\n"),
            Err(CsvError::MissingColumn {
                line: 3,
                column: 2,
                name: "a".into()
            })
        );
        let error = parse("t,a,b\n0,1,2\n0.1,x,3\n").unwrap_err();
        assert_eq!(
            error.to_string(),
            "line 3, column 2 (`a`): `x` is not a finite number"
        );
        assert_eq!(
            parse("t,a\n0,1\n0.2,1\n0.1,1\n"),
            Err(CsvError::NonMonotonicTime {
                line: 4,
                time_s: 0.1,
                previous_s: 0.2
            })
        );
        assert!(matches!(
            parse("time,a\n0,1\n"),
            Err(CsvError::TimeColumn { .. })
        ));
        assert!(matches!(
            parse("t,a\n0,1,2\n"),
            Err(CsvError::ExtraColumn {
                line: 2,
                column: 3,
                ..
            })
        ));
        assert_eq!(
            parse("t,a\n0,nan\n").unwrap_err().to_string(),
            "line 2, column 2 (`a`): `nan` is not a finite number"
        );
    }
}
