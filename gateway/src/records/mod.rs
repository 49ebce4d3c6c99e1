//! Offline recordings: what the command-line tools (`millgate analyze`, `wear`,
//! `discrepancy`, `chatter`) and the tests read instead of live field I/O, on its way
//! to the same analysis.
//!
//! - [`csv`]: a recorded signal as a CSV with a header, first column `t` (s), the
//!   other columns channels (a capture exported by `millgate capture export` among
//!   them);
//! - `stands`: a recording of a tandem mill's stands, read from such a CSV or from a
//!   capture the history keeps.

pub mod csv;
pub(crate) mod stands;
