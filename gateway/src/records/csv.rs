//! Reader of recorded signals: a CSV with a header, first column `t` (s), the other
//! columns channels (torque in kN*m). Errors name the line (1-based) and the column.
//! Lines starting with `#` are comments (kept in [`Table::comments`]): a `# reset`
//! line marks a wear reset between the rows around it ([`Table::resets`]). A capture
//! exported by `millgate capture export` says how the gateway read it in the JSON
//! file beside it (`<name>.json`, or, written before that, in a first comment line
//! `# millgate capture {json}`): [`Table::capture`].
//! A record of bites recorded apart jumps in time between them ([`Table::segments`]).

use std::path::Path;

use crate::history::capture_files::CaptureHeader;

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
    /// Two header cells carry the same name: a channel would be ambiguous.
    #[error("line 1, column {column}: column name `{name}` repeats column {first_column}")]
    DuplicateColumn {
        /// 1-based column number of the repeat.
        column: usize,
        /// The repeated name.
        name: String,
        /// 1-based column number of its first use.
        first_column: usize,
    },
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
    /// A time step departs from the record's median step: rows are missing (or doubled),
    /// and a mean sample rate would misdate every sample after them.
    #[error(
        "line {line}, column 1 (`t`): t steps by {step_s:.6} s from the line before, the \
         record's median step is {median_step_s:.6} s; rows are missing or the sampling is \
         not uniform (each step must be within {tolerance_percent}% of the median)"
    )]
    NonUniformTime {
        /// 1-based line number of the row after the odd step.
        line: usize,
        /// That step, s.
        step_s: f64,
        /// Median step of the record, s.
        median_step_s: f64,
        /// Allowed departure from the mean step, %.
        tolerance_percent: f64,
    },
    /// A torque sample beyond any mill's: a scaling or unit error in the record.
    #[error(
        "line {line}, column {column} (`{name}`): torque {value_knm:e} kN*m lies outside \
         the physical range -{limit_knm:e}..={limit_knm:e} kN*m (a unit or scaling error?)"
    )]
    TorqueOutOfRange {
        /// 1-based line number.
        line: usize,
        /// 1-based column number.
        column: usize,
        /// Header name of the column.
        name: String,
        /// The value, kN*m.
        value_knm: f64,
        /// The largest magnitude accepted, kN*m.
        limit_knm: f64,
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
    /// 1-based line number of each row in the file (blank lines are skipped).
    pub lines: Vec<usize>,
    /// The comment lines (`#` and what follows), in order.
    pub comments: Vec<String>,
    /// Rows (indices into `time_s`) before which a `# reset` comment stands: a wear
    /// reset (the coupling was replaced) between the bites before and after it.
    pub resets: Vec<usize>,
    /// A capture export's header: from its sidecar (`<name>.json`, when [`read`]
    /// found one) or its `# millgate capture` comment (files written before the
    /// sidecar); the error says where it is unreadable.
    pub capture: Option<Result<CaptureHeader, String>>,
}

/// A record of bites recorded apart: runs of uniformly sampled rows (`ranges`, row
/// indices), separated by jumps in time of at least [`SEGMENT_JUMP_S`], every run at
/// the same sample rate.
#[derive(Debug, Clone, PartialEq)]
pub struct Segments {
    /// The sample rate of every run, Hz.
    pub rate_hz: f64,
    /// The runs, in order.
    pub ranges: Vec<std::ops::Range<usize>>,
}

/// A time step at least this long starts a new segment of a record (bites recorded
/// hours or days apart), s; a shorter step off the sample period is missing rows.
pub const SEGMENT_JUMP_S: f64 = 10.0;

/// Largest departure of one time step from the record's mean step, relative.
pub const UNIFORM_TOLERANCE: f64 = 0.01;

/// Largest torque magnitude a record may hold, kN*m: a hundred times the largest
/// rolling-mill drive (about 10 MN*m); beyond it the record is mis-scaled, and its
/// fit would publish numbers of no mill (1e300 overflows the fit's squares).
pub const MAX_TORQUE_KNM: f64 = 1.0e6;

impl Table {
    /// The sample rate, Hz, of a uniformly sampled record: (rows - 1) / (last time -
    /// first time), once every time step is checked to lie within
    /// [`UNIFORM_TOLERANCE`] of the record's median step. A record with missing rows
    /// is an error naming the line after the first odd step: the mean rate would
    /// misdate every sample after it (0.1 s missing from a 0.6 s record read 21 Hz as
    /// 18 Hz).
    pub fn sample_rate_hz(&self) -> Result<f64, CsvError> {
        let n = self.time_s.len();
        let mut steps: Vec<f64> = self.time_s.windows(2).map(|p| p[1] - p[0]).collect();
        let odd_step = |step: f64, median: f64| (step / median - 1.0).abs() > UNIFORM_TOLERANCE;
        steps.sort_by(f64::total_cmp);
        let median_step_s = steps[steps.len() / 2];
        let odd = self
            .time_s
            .windows(2)
            .position(|pair| odd_step(pair[1] - pair[0], median_step_s));
        match odd {
            Some(k) => Err(CsvError::NonUniformTime {
                line: self.lines[k + 1],
                step_s: self.time_s[k + 1] - self.time_s[k],
                median_step_s,
                tolerance_percent: UNIFORM_TOLERANCE * 100.0,
            }),
            None => Ok((n - 1) as f64 / (self.time_s[n - 1] - self.time_s[0])),
        }
    }

    /// The record's segments ([`Segments`]): split where `t` jumps by at least
    /// [`SEGMENT_JUMP_S`]; every other step must lie within [`UNIFORM_TOLERANCE`] of
    /// the median of those steps, else the error names the line after the odd step.
    pub fn segments(&self) -> Result<Segments, CsvError> {
        let steps: Vec<f64> = self.time_s.windows(2).map(|p| p[1] - p[0]).collect();
        let mut inside: Vec<f64> = steps
            .iter()
            .copied()
            .filter(|&step| step < SEGMENT_JUMP_S)
            .collect();
        if inside.is_empty() {
            return Err(CsvError::TooShort);
        }
        inside.sort_by(f64::total_cmp);
        let median_step_s = inside[inside.len() / 2];
        let mut ranges = Vec::new();
        let mut start = 0;
        for (k, &step) in steps.iter().enumerate() {
            if step >= SEGMENT_JUMP_S {
                ranges.push(start..k + 1);
                start = k + 1;
            } else if (step / median_step_s - 1.0).abs() > UNIFORM_TOLERANCE {
                return Err(CsvError::NonUniformTime {
                    line: self.lines[k + 1],
                    step_s: step,
                    median_step_s,
                    tolerance_percent: UNIFORM_TOLERANCE * 100.0,
                });
            }
        }
        ranges.push(start..self.time_s.len());
        let (rows, span) =
            ranges
                .iter()
                .filter(|range| range.len() > 1)
                .fold((0, 0.0), |(rows, span), range| {
                    let duration = self.time_s[range.end - 1] - self.time_s[range.start];
                    (rows + range.len() - 1, span + duration)
                });
        Ok(Segments {
            rate_hz: rows as f64 / span,
            ranges,
        })
    }

    /// The capture header of an exported capture ([`Table::capture`]); `Ok(None)`
    /// for another record, the error saying where the header is unreadable.
    pub fn capture_header(&self) -> Result<Option<&CaptureHeader>, String> {
        self.capture
            .as_ref()
            .map(|header| header.as_ref().map_err(Clone::clone))
            .transpose()
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

    /// [`Self::pick`] for a torque channel (kN*m): also refuses a record with a sample
    /// beyond [`MAX_TORQUE_KNM`], naming its line and column.
    pub(crate) fn pick_torque<'a>(
        &'a self,
        name: Option<&'a str>,
    ) -> Result<(&'a str, &'a [f64]), String> {
        let (name, values) = self.pick(name)?;
        let column = 2 + self.names.iter().position(|n| n == name).unwrap_or(0);
        match values.iter().position(|v| v.abs() > MAX_TORQUE_KNM) {
            Some(row) => Err(CsvError::TorqueOutOfRange {
                line: self.lines[row],
                column,
                name: name.to_string(),
                value_knm: values[row],
                limit_knm: MAX_TORQUE_KNM,
            }
            .to_string()),
            None => Ok((name, values)),
        }
    }
}

/// Reads and parses the CSV at `path`, with the capture header of its sidecar
/// (`<name>.json` beside it) when there is one.
pub fn read(path: &Path) -> Result<Table, CsvError> {
    let text = std::fs::read_to_string(path).map_err(|e| CsvError::Io {
        path: path.display().to_string(),
        message: e.to_string(),
    })?;
    parse_with(&text, CaptureHeader::from_sidecar(path))
}

/// Parses CSV text (comma-separated, cells trimmed, blank lines skipped, `#` lines
/// kept as comments).
pub fn parse(text: &str) -> Result<Table, CsvError> {
    parse_with(text, None)
}

/// Parses CSV text whose capture header, when it has none in a comment, is
/// `sidecar`'s.
fn parse_with(
    text: &str,
    sidecar: Option<Result<CaptureHeader, String>>,
) -> Result<Table, CsvError> {
    let comments: Vec<String> = text
        .lines()
        .filter_map(|l| l.trim().strip_prefix('#'))
        .map(|comment| comment.trim().to_string())
        .collect();
    let capture = CaptureHeader::from_comments(&comments).or(sidecar);
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'));
    let (_, header) = lines.next().ok_or(CsvError::Empty)?;
    let header = parse_header(header)?;
    let columns = Columns {
        may_be_empty: may_be_empty(&header, capture.as_ref()),
        header,
    };
    let mut table = Table {
        names: columns.header[1..].to_vec(),
        time_s: Vec::new(),
        channels: vec![Vec::new(); columns.header.len() - 1],
        lines: Vec::new(),
        comments,
        resets: reset_rows(text),
        capture,
    };
    for (line, row) in lines {
        columns.push_row(&mut table, line, row)?;
    }
    if table.time_s.len() < 2 {
        return Err(CsvError::TooShort);
    }
    Ok(table)
}

/// The data rows before which a `# reset` comment stands (the header is not a row).
fn reset_rows(text: &str) -> Vec<usize> {
    let mut lines_seen = 0_usize;
    let mut resets = Vec::new();
    for line in text.lines().map(str::trim).filter(|l| !l.is_empty()) {
        match line.strip_prefix('#') {
            Some(comment) if comment.trim().eq_ignore_ascii_case("reset") => {
                resets.push(lines_seen.saturating_sub(1));
            }
            Some(_) => {}
            None => lines_seen += 1,
        }
    }
    resets.dedup();
    resets
}

/// The header line's names: `t` first, at least one channel, none twice.
fn parse_header(line: &str) -> Result<Vec<String>, CsvError> {
    let header: Vec<String> = line.split(',').map(|c| c.trim().to_string()).collect();
    if header[0] != "t" {
        return Err(CsvError::TimeColumn {
            found: header[0].clone(),
        });
    }
    if header.len() < 2 {
        return Err(CsvError::NoChannel);
    }
    for (index, name) in header.iter().enumerate() {
        if let Some(first) = header[..index].iter().position(|other| other == name) {
            return Err(CsvError::DuplicateColumn {
                column: index + 1,
                name: name.clone(),
                first_column: first + 1,
            });
        }
    }
    Ok(header)
}

/// Per column of `header`, whether a cell may be empty: a capture's extra channels
/// (`drivelines[].extra_channels`, named in its `capture` header) may lack samples at
/// the window's ends, and an empty cell there reads as NaN.
fn may_be_empty(header: &[String], capture: Option<&Result<CaptureHeader, String>>) -> Vec<bool> {
    let extra: Vec<String> = match capture {
        Some(Ok(capture)) => capture
            .channels
            .iter()
            .filter(|meta| meta.channel.timing.is_some())
            .map(|meta| meta.channel.name.clone())
            .collect(),
        _ => Vec::new(),
    };
    header.iter().map(|name| extra.contains(name)).collect()
}

/// The columns of a CSV: the header's names, and which may hold empty cells.
struct Columns {
    /// The header's names, `t` first.
    header: Vec<String>,
    /// Per column, whether an empty cell reads as NaN.
    may_be_empty: Vec<bool>,
}

impl Columns {
    /// Add data line `line`, `row`, to `table`.
    fn push_row(&self, table: &mut Table, line: usize, row: &str) -> Result<(), CsvError> {
        let header = &self.header;
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
                Some(_) if self.may_be_empty[index] => {
                    table.channels[index - 1].push(f64::NAN);
                    continue;
                }
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
                push_time(table, line, value)?;
            } else {
                table.channels[index - 1].push(value);
            }
        }
        Ok(())
    }
}

/// Add the time `time_s` of data line `line` to `table`: after the previous line's.
fn push_time(table: &mut Table, line: usize, time_s: f64) -> Result<(), CsvError> {
    if let Some(&previous_s) = table.time_s.last() {
        if time_s <= previous_s {
            return Err(CsvError::NonMonotonicTime {
                line,
                time_s,
                previous_s,
            });
        }
    }
    table.time_s.push(time_s);
    table.lines.push(line);
    Ok(())
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
        assert_eq!(table.sample_rate_hz(), Ok(2.0));
        assert_eq!(table.lines, [2, 4]);
    }

    #[test]
    fn a_torque_beyond_any_mill_is_refused_with_its_line_and_column() {
        let table = parse("t,speed,torque\n0,1,112\n\n0.5,1,-1.12e302\n").unwrap();
        let error = table.pick_torque(Some("torque")).unwrap_err();
        assert!(
            error.starts_with("line 4, column 3 (`torque`): torque -1.12e302 kN*m lies outside"),
            "{error}"
        );
        assert!(error.contains("-1e6..=1e6 kN*m"), "{error}");
        // The largest accepted value passes; the plain pick does not look.
        let table = parse("t,torque\n0,1e6\n0.5,-1e6\n").unwrap();
        assert!(table.pick_torque(None).is_ok());
    }

    #[test]
    fn a_repeated_column_name_is_refused_with_both_columns() {
        let error = parse("t,a,b,a\n0,1,2,3\n0.1,1,2,3\n").unwrap_err();
        assert_eq!(
            error.to_string(),
            "line 1, column 4: column name `a` repeats column 2"
        );
        assert!(matches!(
            parse("t,t\n0,1\n1,2\n"),
            Err(CsvError::DuplicateColumn { column: 2, .. })
        ));
    }

    #[test]
    fn missing_rows_are_refused_with_the_line_after_the_gap() {
        // 2 kHz, rows 300..500 (0.1 s) missing; a blank line before the gap shifts the
        // line numbers, which must still be the file's.
        let mut text = String::from("t,a\n");
        for k in (0..1200).filter(|k| !(300..500).contains(k)) {
            text.push_str(&format!("{},1\n", f64::from(k) * 5.0e-4));
            if k == 10 {
                text.push('\n');
            }
        }
        let table = parse(&text).unwrap();
        let error = table.sample_rate_hz().unwrap_err();
        // Row index 300 of the kept rows is sample 500, on line 2 + 300 + 1 (the blank).
        assert!(
            matches!(error, CsvError::NonUniformTime { line: 303, .. }),
            "{error}"
        );
        assert!(
            error
                .to_string()
                .starts_with("line 303, column 1 (`t`): t steps by 0.100500 s"),
            "{error}"
        );
        let uniform = parse("t,a\n0,1\n0.0005,1\n0.001,1\n").unwrap();
        assert!((uniform.sample_rate_hz().unwrap() - 2000.0).abs() < 1e-6);
    }

    #[test]
    fn bites_recorded_days_apart_are_segments_and_reset_comments_are_kept() {
        // Three bursts of 2 kHz samples, in Unix seconds, hours and days apart; a wear
        // reset before the third.
        let mut text = String::from("# recorded on F1\nt,a\n");
        let starts = [1_780_000_000.0, 1_780_003_600.0, 1_780_172_800.0];
        for (n, start) in starts.iter().enumerate() {
            if n == 2 {
                text.push_str("# reset\n");
            }
            for k in 0..100 {
                text.push_str(&format!("{:.6},1\n", start + f64::from(k) * 5.0e-4));
            }
        }
        let table = parse(&text).unwrap();
        let segments = table.segments().unwrap();
        assert_eq!(segments.ranges, [0..100, 100..200, 200..300]);
        assert!((segments.rate_hz - 2000.0).abs() < 0.01, "{segments:?}");
        assert_eq!(table.resets, [200], "the row after the comment");
        assert_eq!(table.comments, ["recorded on F1", "reset"]);
        // Rows missing inside a segment are still an error naming the line.
        let gap = text.replacen(&format!("{:.6},1\n", starts[1] + 50.0 * 5.0e-4), "", 1);
        let error = parse(&gap).unwrap().segments().unwrap_err();
        assert!(
            matches!(error, CsvError::NonUniformTime { line: 153, .. }),
            "{error}"
        );
        // A segment at another rate: the odd step is named too.
        let mut other = text.clone();
        other.push_str(&format!(
            "{:.6},1\n{:.6},1\n",
            1_780_300_000.0, 1_780_300_000.001
        ));
        assert!(matches!(
            parse(&other).unwrap().segments(),
            Err(CsvError::NonUniformTime { line: 305, .. })
        ));
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
