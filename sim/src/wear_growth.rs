//! How a coupling's opened gap grows over months, and when a mill bites: the ground
//! truth for evaluating the wear trend and its forecast (issue 37).
//!
//! - [`GrowthLaw`]: the gap over calendar days (linear, accelerating, starting late,
//!   stable), with the exact day it reaches an alarm ([`GrowthLaw::crossing_day`]);
//!   [`GrowthLaw::draw`] draws one of a kind with the design study's ranges.
//! - [`BiteCalendar`]: seeded bite times over days: two shifts (06:00-14:00,
//!   14:00-22:00) on weekdays, Saturdays half the time, Sundays idle, 0-3 outages of 1-7
//!   days, a Poisson number of bites per shift at uniform times.
//!
//! Both are ports of the design study's prototype (`evaluate.py`: `growth`, `calendar`);
//! day 0 is a Monday, 00:00.

use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Poisson};

/// The gap of one coupling over calendar days (day 0 is the start of the record).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum GrowthLaw {
    /// `start + rate * day`.
    Linear {
        /// Gap at day 0, mrad.
        start_mrad: f64,
        /// Growth, mrad/day.
        rate_mrad_per_day: f64,
    },
    /// The growth rate doubles every `doubling_days`: `start + rate0 * doubling_days /
    /// ln 2 * (2^(day / doubling_days) - 1)`.
    Accelerating {
        /// Gap at day 0, mrad.
        start_mrad: f64,
        /// Growth at day 0, mrad/day.
        rate0: f64,
        /// Days for the growth rate to double, > 0.
        doubling_days: f64,
    },
    /// Flat until `onset_day`, then linear: `start + rate * max(day - onset_day, 0)`.
    LateStart {
        /// Gap until the onset, mrad.
        start_mrad: f64,
        /// Day the growth starts.
        onset_day: f64,
        /// Growth after the onset, mrad/day.
        rate: f64,
    },
    /// A constant gap.
    Stable {
        /// The gap, mrad.
        gap_mrad: f64,
    },
}

/// The kinds of [`GrowthLaw`], for drawing one.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GrowthKind {
    /// [`GrowthLaw::Linear`].
    Linear,
    /// [`GrowthLaw::Accelerating`].
    Accelerating,
    /// [`GrowthLaw::LateStart`].
    LateStart,
    /// [`GrowthLaw::Stable`].
    Stable,
}

impl GrowthKind {
    /// Every kind, in the prototype's order.
    pub const ALL: [Self; 4] = [
        Self::Linear,
        Self::Accelerating,
        Self::LateStart,
        Self::Stable,
    ];

    /// A short name: `linear`, `accelerating`, `late_start`, `stable`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Linear => "linear",
            Self::Accelerating => "accelerating",
            Self::LateStart => "late_start",
            Self::Stable => "stable",
        }
    }
}

impl GrowthLaw {
    /// A law of `kind` with the design study's ranges (uniform): start 0.3-1.5 mrad;
    /// linear 0.012-0.05 mrad/day (0.08-0.35 mrad/week); accelerating from 0.006-0.02
    /// mrad/day doubling every 60-150 days; late start after 20-90 days at 0.015-0.05
    /// mrad/day; stable at 0.3-3.0 mrad.
    pub fn draw(kind: GrowthKind, rng: &mut impl Rng) -> Self {
        let start_mrad = rng.random_range(0.3..1.5);
        match kind {
            GrowthKind::Linear => Self::Linear {
                start_mrad,
                rate_mrad_per_day: rng.random_range(0.012..0.05),
            },
            GrowthKind::Accelerating => Self::Accelerating {
                start_mrad,
                rate0: rng.random_range(0.006..0.02),
                doubling_days: rng.random_range(60.0..150.0),
            },
            GrowthKind::LateStart => Self::LateStart {
                start_mrad,
                onset_day: rng.random_range(20.0..90.0),
                rate: rng.random_range(0.015..0.05),
            },
            GrowthKind::Stable => Self::Stable {
                gap_mrad: rng.random_range(0.3..3.0),
            },
        }
    }

    /// The kind of this law.
    pub fn kind(&self) -> GrowthKind {
        match self {
            Self::Linear { .. } => GrowthKind::Linear,
            Self::Accelerating { .. } => GrowthKind::Accelerating,
            Self::LateStart { .. } => GrowthKind::LateStart,
            Self::Stable { .. } => GrowthKind::Stable,
        }
    }

    /// The gap at `day` (>= 0), mrad.
    pub fn gap_at(&self, day: f64) -> f64 {
        match *self {
            Self::Linear {
                start_mrad,
                rate_mrad_per_day,
            } => start_mrad + rate_mrad_per_day * day,
            Self::Accelerating {
                start_mrad,
                rate0,
                doubling_days,
            } => {
                start_mrad
                    + rate0 * doubling_days / std::f64::consts::LN_2
                        * ((day / doubling_days).exp2() - 1.0)
            }
            Self::LateStart {
                start_mrad,
                onset_day,
                rate,
            } => start_mrad + rate * (day - onset_day).max(0.0),
            Self::Stable { gap_mrad } => gap_mrad,
        }
    }

    /// The first day >= 0 at which the gap reaches `alarm_mrad` (0 when it starts at or
    /// above it), exactly; `None` when it never does.
    pub fn crossing_day(&self, alarm_mrad: f64) -> Option<f64> {
        let start = self.gap_at(0.0);
        if start >= alarm_mrad {
            return Some(0.0);
        }
        let rise = alarm_mrad - start;
        let day = match *self {
            Self::Linear {
                rate_mrad_per_day, ..
            } => rise / rate_mrad_per_day,
            Self::Accelerating {
                rate0,
                doubling_days,
                ..
            } => {
                // 2^(d / T) = 1 + rise ln 2 / (rate0 T)
                doubling_days
                    * (1.0 + rise * std::f64::consts::LN_2 / (rate0 * doubling_days)).log2()
            }
            Self::LateStart {
                onset_day, rate, ..
            } => onset_day + rise / rate,
            Self::Stable { .. } => return None,
        };
        (day.is_finite() && day >= 0.0).then_some(day)
    }
}

/// When bites come: two 8-hour shifts a weekday with a Poisson number of bites each at
/// uniform times, Saturdays worked half the time, Sundays idle, and 0-3 outages of 1-7
/// days starting after day 5.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BiteCalendar {
    /// Days covered from day 0 (a Monday).
    pub days: f64,
    /// Mean bites per shift (the prototype's bites per day / 2), >= 0.
    pub bites_per_shift: f64,
}

/// The bites of a [`BiteCalendar`] and the outages that removed some.
#[derive(Debug, Clone, PartialEq)]
pub struct BiteTimes {
    /// Bite times, days from day 0, ascending.
    pub times_days: Vec<f64>,
    /// Outages `(start, end)`, days: no bite in `start <= t < end`.
    pub outages_days: Vec<(f64, f64)>,
}

/// The shifts' start and end, fractions of a day.
const SHIFTS: [(f64, f64); 2] = [(6.0 / 24.0, 14.0 / 24.0), (14.0 / 24.0, 22.0 / 24.0)];

impl BiteCalendar {
    /// The bite times of calendar `seed` (the same seed, the same times).
    pub fn generate(&self, seed: u64) -> BiteTimes {
        let mut rng = StdRng::seed_from_u64(seed);
        let mut outages_days = Vec::new();
        if self.days > 5.0 {
            for _ in 0..rng.random_range(0..=3) {
                let start = rng.random_range(5.0..self.days);
                outages_days.push((start, start + rng.random_range(1.0..7.0)));
            }
        }
        let per_shift = Poisson::new(self.bites_per_shift).ok();
        let mut times_days = Vec::new();
        for day in 0..self.days.max(0.0).ceil() as u64 {
            let weekday = day % 7;
            if weekday == 6 || (weekday == 5 && rng.random_bool(0.5)) {
                continue;
            }
            for (from, to) in SHIFTS {
                let count = per_shift.map_or(0, |p| p.sample(&mut rng) as usize);
                let mut shift: Vec<f64> = (0..count)
                    .map(|_| day as f64 + rng.random_range(from..to))
                    .collect();
                shift.sort_by(f64::total_cmp);
                times_days.extend(shift.into_iter().filter(|&t| {
                    t < self.days && !outages_days.iter().any(|&(a, b)| a <= t && t < b)
                }));
            }
        }
        BiteTimes {
            times_days,
            outages_days,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The first day the gap reaches `alarm`, by bisection on `gap_at` between 0 and
    /// `limit` (the law's gap grows monotonically).
    fn bisect(law: &GrowthLaw, alarm: f64, limit: f64) -> Option<f64> {
        if law.gap_at(0.0) >= alarm {
            return Some(0.0);
        }
        if law.gap_at(limit) < alarm {
            return None;
        }
        let (mut low, mut high) = (0.0, limit);
        for _ in 0..200 {
            let mid = 0.5 * (low + high);
            if law.gap_at(mid) >= alarm {
                high = mid;
            } else {
                low = mid;
            }
        }
        Some(high)
    }

    #[test]
    fn crossing_day_agrees_with_bisection_on_gap_at() {
        let mut rng = StdRng::seed_from_u64(37);
        for i in 0..400 {
            let law = GrowthLaw::draw(GrowthKind::ALL[i % 4], &mut rng);
            assert_eq!(law.kind(), GrowthKind::ALL[i % 4]);
            for alarm in [0.2, 2.0, 4.0, 6.5] {
                let exact = law.crossing_day(alarm);
                let bisected = bisect(&law, alarm, 1e5);
                match (exact, bisected) {
                    (Some(a), Some(b)) => {
                        assert!(
                            (a - b).abs() < 1e-6 * b.max(1.0),
                            "{law:?} {alarm}: {a} {b}"
                        );
                        assert!((law.gap_at(a) - alarm).abs() < 1e-9 || a == 0.0);
                    }
                    (None, None) => assert_eq!(law.kind(), GrowthKind::Stable),
                    other => panic!("{law:?} {alarm}: {other:?}"),
                }
            }
        }
    }

    #[test]
    fn the_laws_have_their_shapes() {
        let late = GrowthLaw::LateStart {
            start_mrad: 1.0,
            onset_day: 30.0,
            rate: 0.02,
        };
        assert_eq!(late.gap_at(29.0), 1.0);
        assert!((late.gap_at(80.0) - 2.0).abs() < 1e-12);
        let fast = GrowthLaw::Accelerating {
            start_mrad: 1.0,
            rate0: 0.01,
            doubling_days: 100.0,
        };
        // The rate doubles every 100 days: the slope at day 100 is 0.02 mrad/day.
        let slope = (fast.gap_at(100.001) - fast.gap_at(99.999)) / 0.002;
        assert!((slope - 0.02).abs() < 1e-8, "{slope}");
        assert_eq!(GrowthLaw::Stable { gap_mrad: 2.0 }.crossing_day(4.0), None);
        assert_eq!(
            GrowthLaw::Stable { gap_mrad: 5.0 }.crossing_day(4.0),
            Some(0.0)
        );
        let shrinking = GrowthLaw::Linear {
            start_mrad: 2.0,
            rate_mrad_per_day: -0.01,
        };
        assert_eq!(shrinking.crossing_day(4.0), None);
    }

    #[test]
    fn the_calendar_is_sorted_idle_on_sundays_and_reproducible() {
        let calendar = BiteCalendar {
            days: 300.0,
            bites_per_shift: 10.0,
        };
        let mut saturdays = 0;
        let mut outages = 0;
        for seed in 0..20 {
            let bites = calendar.generate(seed);
            assert_eq!(bites, calendar.generate(seed), "reproducible");
            let times = &bites.times_days;
            assert!(times.windows(2).all(|w| w[0] <= w[1]), "sorted");
            assert!(times.iter().all(|&t| (0.0..300.0).contains(&t)));
            assert!(times.iter().all(|&t| (t as u64) % 7 != 6), "no Sunday bite");
            assert!(times.iter().all(|&t| {
                let hour = (t - t.floor()) * 24.0;
                (6.0..22.0).contains(&hour)
            }));
            for &(a, b) in &bites.outages_days {
                assert!(times.iter().all(|&t| !(a <= t && t < b)), "outage");
                assert!(a >= 5.0 && (1.0..7.0).contains(&(b - a)));
            }
            assert!(bites.outages_days.len() <= 3);
            outages += bites.outages_days.len();
            // ~214 weekdays + ~21 Saturdays, 20 bites each, less the outages.
            assert!((3500..5200).contains(&times.len()), "{}", times.len());
            let worked: std::collections::BTreeSet<u64> = times
                .iter()
                .map(|&t| t as u64)
                .filter(|d| d % 7 == 5)
                .collect();
            saturdays += worked.len();
        }
        assert_ne!(calendar.generate(1), calendar.generate(2));
        // 43 Saturdays a calendar, half worked: 430 over 20 calendars, less outages.
        assert!((340..480).contains(&saturdays), "{saturdays}");
        assert!(outages > 10, "outages happen: {outages}");
        let idle = BiteCalendar {
            days: 10.0,
            bites_per_shift: 0.0,
        };
        assert!(idle.generate(3).times_days.is_empty());
    }
}
