//! Times in the history file: UTC as ISO-8601 text with milliseconds,
//! `2026-11-22T16:37:33.123Z`.
//!
//! Text, not Unix seconds, so that `sqlite3`, Python's `datetime.fromisoformat`,
//! spreadsheets and SQLite's own date functions (`julianday(time)`, `strftime`) read
//! the columns as they are. The width is fixed (years 0000..=9999), so text order is
//! time order and range queries use the indexes.
//!
//! The calendar conversion is written out here (Howard Hinnant's `days_from_civil`
//! and `civil_from_days`, proleptic Gregorian) rather than taken from a date crate: it
//! is the only date arithmetic the gateway needs, 30 lines against a dependency.

use std::fmt;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

/// A UTC time with millisecond resolution, as stored in the history.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct UtcTime {
    unix_ms: i64,
}

/// A time that could not be read.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "\"{0}\" is not a time (use ISO-8601 UTC: 2026-11-22, 2026-11-22T16:30, \
     2026-11-22T16:30:05Z or 2026-11-22T16:30:05.250Z; or Unix seconds)"
)]
pub struct TimeError(pub String);

fn days_from_civil(year: i64, month: i64, day: i64) -> i64 {
    let year = if month <= 2 { year - 1 } else { year };
    let era = year.div_euclid(400);
    let year_of_era = year - era * 400;
    let day_of_year = (153 * (month + if month > 2 { -3 } else { 9 }) + 2) / 5 + day - 1;
    let day_of_era = year_of_era * 365 + year_of_era / 4 - year_of_era / 100 + day_of_year;
    era * 146_097 + day_of_era - 719_468
}

fn civil_from_days(days: i64) -> (i64, i64, i64) {
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let day_of_era = z - era * 146_097;
    let year_of_era =
        (day_of_era - day_of_era / 1460 + day_of_era / 36_524 - day_of_era / 146_096) / 365;
    let day_of_year = day_of_era - (365 * year_of_era + year_of_era / 4 - year_of_era / 100);
    let mp = (5 * day_of_year + 2) / 153;
    let day = day_of_year - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = year_of_era + era * 400 + i64::from(month <= 2);
    (year, month, day)
}

impl UtcTime {
    /// Milliseconds since the Unix epoch.
    pub fn from_unix_ms(unix_ms: i64) -> Self {
        Self { unix_ms }
    }

    /// The current time.
    pub fn now() -> Self {
        Self::from_system(SystemTime::now())
    }

    /// `time`, truncated to the millisecond.
    pub fn from_system(time: SystemTime) -> Self {
        let unix_ms = match time.duration_since(UNIX_EPOCH) {
            Ok(after) => i64::try_from(after.as_millis()).unwrap_or(i64::MAX),
            Err(before) => -i64::try_from(before.duration().as_millis()).unwrap_or(i64::MAX),
        };
        Self { unix_ms }
    }

    /// Milliseconds since the Unix epoch.
    pub fn unix_ms(self) -> i64 {
        self.unix_ms
    }

    /// Seconds since the Unix epoch.
    pub(crate) fn unix_s(self) -> f64 {
        self.unix_ms as f64 / 1000.0
    }

    /// As a [`SystemTime`].
    pub fn to_system(self) -> SystemTime {
        let magnitude = Duration::from_millis(self.unix_ms.unsigned_abs());
        if self.unix_ms >= 0 {
            UNIX_EPOCH + magnitude
        } else {
            UNIX_EPOCH - magnitude
        }
    }

    /// This time moved by `days` calendar days (negative: back), to the millisecond.
    pub fn plus_days(self, days: f64) -> Self {
        // `as` saturates: a forecast a million years out stays a time.
        let ms = (days * 86_400_000.0).round() as i64;
        Self {
            unix_ms: self.unix_ms.saturating_add(ms),
        }
    }

    /// This time moved back by `duration`.
    pub fn minus(self, duration: Duration) -> Self {
        let ms = i64::try_from(duration.as_millis()).unwrap_or(i64::MAX);
        Self {
            unix_ms: self.unix_ms.saturating_sub(ms),
        }
    }

    /// Reads `text`: an ISO-8601 date (`2026-11-22`, midnight UTC) or date and time
    /// (`T` or a space between, minutes, optional seconds and fraction, optional `Z`
    /// or `+00:00`), or Unix seconds (`1795000000`). Other offsets are refused:
    /// the history is in UTC, and a silent conversion would hide a mistake.
    ///
    /// ```
    /// use millgate::state::time::UtcTime;
    /// let t = UtcTime::parse("2026-11-22T16:37:33.123Z").unwrap();
    /// assert_eq!(t.to_string(), "2026-11-22T16:37:33.123Z");
    /// assert_eq!(UtcTime::parse("1970-01-02").unwrap().unix_ms(), 86_400_000);
    /// assert_eq!(UtcTime::parse("86400").unwrap().unix_ms(), 86_400_000);
    /// assert!(UtcTime::parse("2026-02-30").is_err());
    /// ```
    pub fn parse(text: &str) -> Result<Self, TimeError> {
        let error = || TimeError(text.to_owned());
        let trimmed = text.trim();
        if !trimmed.is_empty() && trimmed.bytes().all(|b| b.is_ascii_digit()) && trimmed.len() > 4 {
            let seconds: i64 = trimmed.parse().map_err(|_| error())?;
            return seconds
                .checked_mul(1000)
                .map(Self::from_unix_ms)
                .ok_or_else(error);
        }
        let body = trimmed
            .strip_suffix('Z')
            .or_else(|| trimmed.strip_suffix("+00:00"))
            .unwrap_or(trimmed);
        let (date, clock) = match body.split_once(['T', ' ']) {
            Some((date, clock)) => (date, Some(clock)),
            None => (body, None),
        };
        let number = |part: &str, digits: usize| -> Result<i64, TimeError> {
            if part.len() == digits && part.bytes().all(|b| b.is_ascii_digit()) {
                part.parse().map_err(|_| error())
            } else {
                Err(error())
            }
        };
        let mut date_parts = date.split('-');
        let year = number(date_parts.next().ok_or_else(error)?, 4)?;
        let month = number(date_parts.next().ok_or_else(error)?, 2)?;
        let day = number(date_parts.next().ok_or_else(error)?, 2)?;
        if date_parts.next().is_some() || !(1..=12).contains(&month) || day < 1 {
            return Err(error());
        }
        let days = days_from_civil(year, month, day);
        if civil_from_days(days) != (year, month, day) {
            return Err(error());
        }
        let mut ms = days * 86_400_000;
        if let Some(clock) = clock {
            let (hms, fraction) = match clock.split_once('.') {
                Some((hms, fraction)) => (hms, Some(fraction)),
                None => (clock, None),
            };
            let mut parts = hms.split(':');
            let hour = number(parts.next().ok_or_else(error)?, 2)?;
            let minute = number(parts.next().ok_or_else(error)?, 2)?;
            let second = parts.next().map_or(Ok(0), |s| number(s, 2))?;
            if parts.next().is_some() || hour > 23 || minute > 59 || second > 59 {
                return Err(error());
            }
            let millis = match fraction {
                Some(f) if !f.is_empty() && f.bytes().all(|b| b.is_ascii_digit()) => {
                    let padded: String = f.chars().chain("000".chars()).take(3).collect();
                    padded.parse::<i64>().map_err(|_| error())?
                }
                Some(_) => return Err(error()),
                None => 0,
            };
            ms += ((hour * 60 + minute) * 60 + second) * 1000 + millis;
        }
        Ok(Self { unix_ms: ms })
    }
}

impl fmt::Display for UtcTime {
    /// `YYYY-MM-DDTHH:MM:SS.mmmZ`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let days = self.unix_ms.div_euclid(86_400_000);
        let ms_of_day = self.unix_ms.rem_euclid(86_400_000);
        let (year, month, day) = civil_from_days(days);
        let (seconds, millis) = (ms_of_day / 1000, ms_of_day % 1000);
        write!(
            f,
            "{year:04}-{month:02}-{day:02}T{:02}:{:02}:{:02}.{millis:03}Z",
            seconds / 3600,
            seconds / 60 % 60,
            seconds % 60
        )
    }
}

/// Serialized as its ISO-8601 text, the form the file and the exports use.
impl serde::Serialize for UtcTime {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.collect_str(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips_across_leap_years_centuries_and_before_the_epoch() {
        // Every 1000th day from 1600 to 2400 plus odd milliseconds.
        for days in (days_from_civil(1600, 1, 1)..days_from_civil(2400, 1, 1)).step_by(997) {
            let time = UtcTime::from_unix_ms(days * 86_400_000 + 45_296_789);
            let text = time.to_string();
            assert_eq!(UtcTime::parse(&text), Ok(time), "{text}");
        }
    }

    #[test]
    fn known_dates() {
        assert_eq!(
            UtcTime::from_unix_ms(0).to_string(),
            "1970-01-01T00:00:00.000Z"
        );
        // 2000-02-29 (a leap day of a century divisible by 400), 951782400 s.
        assert_eq!(
            UtcTime::from_unix_ms(951_782_400_000).to_string(),
            "2000-02-29T00:00:00.000Z"
        );
        assert!(
            UtcTime::parse("1900-02-29").is_err(),
            "1900 is no leap year"
        );
        assert_eq!(
            UtcTime::parse("2026-11-22 16:30").unwrap(),
            UtcTime::parse("2026-11-22T16:30:00.000+00:00").unwrap()
        );
        assert_eq!(
            UtcTime::parse("2026-11-22T16:30:00.5Z").unwrap().unix_ms() % 1000,
            500
        );
        for bad in [
            "",
            "2026-1-2",
            "2026-11-22T25:00",
            "2026-11-22T10:00+02:00",
            "yesterday",
        ] {
            assert!(UtcTime::parse(bad).is_err(), "{bad}");
        }
        let error = UtcTime::parse("yesterday").unwrap_err().to_string();
        assert!(error.starts_with("\"yesterday\" is not a time"), "{error}");
    }

    #[test]
    fn system_time_round_trip() {
        let now = SystemTime::now();
        let time = UtcTime::from_system(now);
        let back = time.to_system();
        assert!(now.duration_since(back).unwrap() < Duration::from_millis(1));
    }
}
