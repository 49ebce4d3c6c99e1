//! Load-time errors: every problem found in a configuration, each naming the file,
//! the key and what is allowed.
//!
//! The house style asks for small `Copy` error enums in `config`. That works for a
//! single bad field of a known struct, but a configuration error has to say *which*
//! file, *which* element of a list (`channels[2]`), the value found and the names that
//! would have been accepted (`known: spindle_top, spindle_bottom`). Those are strings
//! only known at run time, and a plant engineer fixing a file wants all problems at
//! once, so the error is a list of `{ file, key, message }` records instead.

use std::fmt;

/// One problem in a configuration file.
///
/// Displayed as `<file>: <key>: <message>`, for example
/// `mill.toml: drivelines[0].torque: unknown channel "spindel_top" (known: spindle_top)`.
/// For TOML syntax errors `key` is the position, `line 12, column 5`. For problems
/// with the file as a whole (it cannot be read) `key` is empty and the display is
/// `<file>: <message>`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Problem {
    /// The configuration file as the user named it.
    pub file: String,
    /// Key path inside the file (`sources.modbus[0].unit_id`), or a position.
    pub key: String,
    /// What is wrong and what is allowed.
    pub message: String,
}

impl fmt::Display for Problem {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.key.is_empty() {
            write!(f, "{}: {}", self.file, self.message)
        } else {
            write!(f, "{}: {}: {}", self.file, self.key, self.message)
        }
    }
}

/// All problems found while loading a configuration; never empty.
///
/// Displays one [`Problem`] per line, in the order found.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ConfigError {
    /// The problems, at least one.
    pub problems: Vec<Problem>,
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (index, problem) in self.problems.iter().enumerate() {
            if index > 0 {
                writeln!(f)?;
            }
            write!(f, "{problem}")?;
        }
        Ok(())
    }
}

impl std::error::Error for ConfigError {}

/// Collects problems for one file while loading it.
#[derive(Debug)]
pub(crate) struct Report {
    file: String,
    problems: Vec<Problem>,
}

impl Report {
    pub(crate) fn new(file: &str) -> Self {
        Report {
            file: file.to_owned(),
            problems: Vec::new(),
        }
    }

    /// Records a problem at `key`.
    /// Record a problem. Control characters in `key` and `message` (a user's name
    /// quoted in a list of known names, a key with a line break) are escaped, so each
    /// problem stays one line naming its file.
    pub(crate) fn push(&mut self, key: impl Into<String>, message: impl Into<String>) {
        self.problems.push(Problem {
            file: self.file.clone(),
            key: one_line(key.into()),
            message: one_line(message.into()),
        });
    }

    pub(crate) fn is_empty(&self) -> bool {
        self.problems.is_empty()
    }

    /// `Ok(value)` when nothing was recorded, else all problems. A missing value
    /// with no problem recorded would be a bug in the checks; it is reported rather
    /// than turned into a panic.
    pub(crate) fn finish<T>(mut self, value: Option<T>) -> Result<T, ConfigError> {
        match value {
            Some(value) if self.problems.is_empty() => Ok(value),
            _ => {
                if self.problems.is_empty() {
                    self.push(
                        "",
                        "internal error: rejected without a reason (please report)",
                    );
                }
                Err(ConfigError {
                    problems: self.problems,
                })
            }
        }
    }
}

/// 1-based line and column (in characters) of byte offset `offset` in `text`.
///
/// Offsets past the end or inside a multi-byte character are clamped to the
/// nearest preceding character boundary.
pub(crate) fn line_column(text: &str, offset: usize) -> (usize, usize) {
    let mut offset = offset.min(text.len());
    while !text.is_char_boundary(offset) {
        offset -= 1;
    }
    let before = &text[..offset];
    let line = before.matches('\n').count() + 1;
    let line_start = before.rfind('\n').map_or(0, |newline| newline + 1);
    let column = before[line_start..].chars().count() + 1;
    (line, column)
}

/// `text` with its control characters escaped (`\n`, `\u{0}`), unchanged when it has
/// none.
fn one_line(text: String) -> String {
    if text.chars().any(char::is_control) {
        text.chars()
            .map(|c| {
                if c.is_control() {
                    c.escape_default().to_string()
                } else {
                    c.to_string()
                }
            })
            .collect()
    } else {
        text
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn line_column_counts_from_one() {
        let text = "a = 1\nbb = 2\n";
        assert_eq!(line_column(text, 0), (1, 1));
        assert_eq!(line_column(text, 4), (1, 5));
        assert_eq!(line_column(text, 6), (2, 1));
        assert_eq!(line_column(text, 11), (2, 6));
        assert_eq!(line_column(text, 100), (3, 1));
    }

    #[test]
    fn line_column_counts_characters_not_bytes() {
        let text = "name = \"Walzstraße\" x";
        let offset = text.find('x').expect("x is in the text");
        assert_eq!(line_column(text, offset), (1, 21));
        // Inside the two-byte 'ß': clamped back to its start.
        let sharp_s = text.find('ß').expect("sharp s is in the text");
        assert_eq!(line_column(text, sharp_s + 1), (1, 17));
    }

    #[test]
    fn display_is_one_problem_per_line() {
        let error = ConfigError {
            problems: vec![
                Problem {
                    file: "mill.toml".into(),
                    key: "channels[2].sample_rate_hz".into(),
                    message: "-5 is not allowed (must be > 0 Hz)".into(),
                },
                Problem {
                    file: "mill.toml".into(),
                    key: String::new(),
                    message: "cannot read the file: not found".into(),
                },
            ],
        };
        assert_eq!(
            error.to_string(),
            "mill.toml: channels[2].sample_rate_hz: -5 is not allowed (must be > 0 Hz)\n\
             mill.toml: cannot read the file: not found"
        );
    }
}
