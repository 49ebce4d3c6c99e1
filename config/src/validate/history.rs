//! `[history]`: the event history file and its retention.

use std::ops::RangeInclusive;

use crate::raw::RawHistory;
use crate::{CaptureSettings, History, Synchronous};

use super::Checker;
use super::Written;

/// Days events are kept when `retention_days` is not given: a year and a month, so a
/// year-on-year comparison of the wear trend still finds last year's month.
pub(crate) const DEFAULT_RETENTION_DAYS: i64 = 400;
/// Allowed retention, days (100 years at most).
const RETENTION_DAYS: RangeInclusive<i64> = 1..=36_500;
/// Largest data size when `max_size_mb` is not given, MiB.
pub(crate) const DEFAULT_MAX_SIZE_MB: i64 = 1024;
/// Allowed data sizes, MiB (1 TiB at most).
const MAX_SIZE_MB: RangeInclusive<i64> = 1..=1_048_576;

impl Checker<'_> {
    pub(super) fn history(&mut self, raw: &RawHistory) -> Option<History> {
        let path = self.history_path("history.path", &raw.path);
        let retention_days = self.int_in(
            "history.retention_days",
            raw.retention_days.unwrap_or(DEFAULT_RETENTION_DAYS),
            RETENTION_DAYS,
            " days",
        );
        let max_size_mb = self.int_in(
            "history.max_size_mb",
            raw.max_size_mb.unwrap_or(DEFAULT_MAX_SIZE_MB),
            MAX_SIZE_MB,
            " MiB",
        );
        let max_size_mb = u32::try_from(max_size_mb?).ok()?;
        let captures = self.captures(raw, max_size_mb);
        let synchronous = match &raw.synchronous {
            Some(text) => self.choice(
                "history.synchronous",
                "setting",
                text,
                &Synchronous::ALL,
                Synchronous::name,
            ),
            None => Some(Synchronous::default()),
        };
        Some(History {
            path: path?,
            retention_days: u32::try_from(retention_days?).ok()?,
            max_size_mb,
            captures: captures?,
            synchronous: synchronous?,
        })
    }

    /// The capture keys of `[history]` in a file of `max_size_mb` MiB.
    fn captures(&mut self, raw: &RawHistory, max_size_mb: u32) -> Option<CaptureSettings> {
        let defaults = CaptureSettings::defaults(max_size_mb);
        let half = i64::from(max_size_mb / 2).max(1);
        let max_mb = self.int_in(
            "history.captures_max_mb",
            raw.captures_max_mb.unwrap_or(i64::from(defaults.max_mb)),
            1..=half,
            " MiB (at most half of history.max_size_mb)",
        );
        let thin_after_days = self.int_in(
            "history.captures_thin_after_days",
            raw.captures_thin_after_days
                .unwrap_or(i64::from(defaults.thin_after_days)),
            RETENTION_DAYS,
            " days",
        );
        let keep_every = self.int_in(
            "history.captures_keep_every",
            raw.captures_keep_every
                .unwrap_or(i64::from(defaults.keep_every)),
            1..=1000,
            "",
        );
        Some(CaptureSettings {
            enabled: raw.captures.unwrap_or(defaults.enabled),
            max_mb: u32::try_from(max_mb?).ok()?,
            thin_after_days: u32::try_from(thin_after_days?).ok()?,
            keep_every: u32::try_from(keep_every?).ok()?,
        })
    }

    /// The history file at `path` (see [`Checker::written_path`]), whose folder
    /// exists; the file itself may not exist yet (it is created at the first start).
    fn history_path(&mut self, key: &str, path: &str) -> Option<std::path::PathBuf> {
        if path.trim().is_empty() {
            self.report.push(
                key,
                "must not be empty (the SQLite file, e.g. \"history.db\")",
            );
            return None;
        }
        let (resolved, resolution) = self.written_path(path, Written::State);
        if resolved.is_dir() {
            self.report.push(
                key,
                format!("\"{path}\" is a folder (must be a file, e.g. \"{path}/history.db\")"),
            );
            return None;
        }
        let folder = match resolved.parent() {
            Some(folder) if !folder.as_os_str().is_empty() => folder.to_path_buf(),
            _ => std::path::PathBuf::from("."),
        };
        if !folder.is_dir() {
            self.report.push(
                key,
                format!(
                    "the folder of \"{path}\" does not exist (looked for {}; create it, \
                     writable by the service's user; {resolution})",
                    folder.display()
                ),
            );
            return None;
        }
        Some(resolved)
    }
}
