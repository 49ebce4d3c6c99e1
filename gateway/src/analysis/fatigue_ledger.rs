//! The fatigue ledger of a driveline in the service: every sample of its torque
//! channel counted by one streaming rainflow ([`millgate_dsp::rainflow`], the
//! configured gate), each closed cycle's Miner damage added to every component's
//! consumed life ([`millgate_dsp::miner`]), per bite and per UTC day.
//!
//! - **The whole stream**, not the bite windows: a bar's entry and exit, its largest
//!   cycle, close on the entries after it. A bite's damage is what closed since the
//!   bite before, up to the end of its window.
//! - **Untrusted torque is not counted as cycles silently**: a gap in the stream
//!   (lost samples, a saturated sample: the readers make it a gap; a stale or lost
//!   source) **cuts** it: the residue is closed as half cycles, as ASTM E1049-85 ends
//!   a record (counted in the life used: a cycle that spans the cut is counted as its
//!   two halves), and the count starts afresh. Non-finite samples are skipped by the
//!   counter. Either makes the next bite's damage untrusted: it has no value in the
//!   outputs (its quality bit clear), it stays in the life used, and the cuts are
//!   counted (`fatigue_stream_cuts`).
//! - **The rate** of each component is its damage over the last
//!   [`RATE_WINDOW_DAYS`] UTC days (today's part included) divided by the days of
//!   that window it was counted (since its installation or the ledger's start); under
//!   [`MIN_RATE_DAYS`] of them there is no rate. Days the gateway did not run count as
//!   days without damage.
//! - **The forecast** of reaching `fatigue.life_limit` uses the gap forecast's states
//!   ([`ForecastState`]): `forecast` (days given), `at_alarm` (at or over the limit),
//!   `not_growing` (no damage in the window: not consuming), `beyond_horizon` (later
//!   than `wear.horizon_days`), `too_few_bites` (no rate yet).
//! - **Saved form** (JSON, the history's `driveline_state.fatigue_ledger`): each
//!   component's life used, installation time and days, and the rainflow residue, so a
//!   restart continues the count where the last bite left it. The cycles closed after
//!   the last bite recorded before a stop are lost (at most one bite's worth).

use std::collections::VecDeque;

use millgate_config::FatigueSettings;
use millgate_dsp::miner::SnCurve;
use millgate_dsp::rainflow::{
    Cycle, Rainflow, RainflowSettings, RainflowSettingsError, RainflowState,
};
use serde::{Deserialize, Serialize};

use super::fatigue::STACK;
use crate::state::results::{ComponentLife, FatigueFigures, ForecastState};

/// Days of damage the consumption rate is taken over.
pub const RATE_WINDOW_DAYS: i64 = 7;
/// Fewest days counted in the window for a rate.
pub const MIN_RATE_DAYS: f64 = 1.0;
/// Milliseconds per day.
const MS_PER_DAY: i64 = 86_400_000;

/// One component's account.
#[derive(Debug, Clone)]
struct Account {
    name: String,
    curve: SnCurve,
    /// Miner's sum since installation.
    life_used: f64,
    /// Damage closed since the last bite.
    since_bite: f64,
    /// Installation (the last reset) or the ledger's start, ms since the epoch.
    installed_unix_ms: i64,
    /// Damage per UTC day (day number since the epoch), oldest first, the last
    /// [`RATE_WINDOW_DAYS`] days with damage at most.
    days: VecDeque<(i64, f64)>,
}

impl Account {
    fn add(&mut self, damage: f64, day: i64) {
        if damage <= 0.0 {
            return;
        }
        self.life_used += damage;
        self.since_bite += damage;
        match self.days.back_mut() {
            Some((last, sum)) if *last >= day => *sum += damage,
            _ => {
                self.days.push_back((day, damage));
                while self.days.len() > RATE_WINDOW_DAYS as usize {
                    self.days.pop_front();
                }
            }
        }
    }

    /// Life per day over the window ending at `now_ms`, when a day of it is counted.
    fn rate_per_day(&self, now_ms: i64) -> Option<f64> {
        let today = now_ms.div_euclid(MS_PER_DAY);
        let first_day = today - (RATE_WINDOW_DAYS - 1);
        let start = (first_day * MS_PER_DAY).max(self.installed_unix_ms);
        let days = (now_ms - start) as f64 / MS_PER_DAY as f64;
        if days < MIN_RATE_DAYS {
            return None;
        }
        let damage: f64 = self
            .days
            .iter()
            .filter(|(day, _)| *day >= first_day)
            .map(|(_, damage)| damage)
            .sum();
        Some(damage / days)
    }

    /// Its figures at `now_ms` against `limit` within `horizon_days`, with the bite's
    /// damage when it can be trusted.
    fn figures(
        &self,
        index: usize,
        now_ms: i64,
        (limit, horizon_days): (f64, f64),
        bite_damage: Option<f64>,
    ) -> FatigueFigures {
        let rate = self.rate_per_day(now_ms);
        let (forecast, days) = match rate {
            _ if self.life_used >= limit => (ForecastState::AtAlarm, Some(0.0)),
            None => (ForecastState::TooFewBites, None),
            Some(rate) if rate <= 0.0 => (ForecastState::NotGrowing, None),
            Some(rate) => match (limit - self.life_used) / rate {
                days if days > horizon_days => (ForecastState::BeyondHorizon, None),
                days => (ForecastState::Forecast, Some(days)),
            },
        };
        FatigueFigures {
            component: index,
            life_used: self.life_used,
            bite_damage,
            rate_per_day: rate,
            forecast,
            days_to_limit: days,
            limit_date_unix_ms: days.map(|d| now_ms + (d * MS_PER_DAY as f64).round() as i64),
        }
    }
}

/// What a bite of the ledger gives the published results.
#[derive(Debug, Clone, PartialEq)]
pub struct LedgerBite {
    /// The worst component's figures (the most life used; the first of equals).
    pub worst: FatigueFigures,
    /// Every component's, in config order.
    pub components: Vec<ComponentLife>,
    /// Stream cuts since start.
    pub stream_cuts: u64,
}

/// A driveline's fatigue ledger: the counter and each component's account.
#[derive(Debug)]
pub(crate) struct FatigueLedger {
    counter: Rainflow<STACK>,
    state: RainflowState<STACK>,
    components: Vec<Account>,
    life_limit: f64,
    horizon_days: f64,
    /// The stream was cut or had non-finite samples since the last bite.
    untrusted_since_bite: bool,
    /// Cuts since start.
    stream_cuts: u64,
    /// Non-finite samples of the state as of the last bite.
    non_finite_seen: u64,
}

/// The saved form of a ledger.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct Saved {
    components: Vec<SavedComponent>,
    /// The rainflow residue: reversals oldest first, then the running extreme and
    /// whether the torque is rising towards it (none before the first move).
    residue: Vec<f64>,
    pending: Option<(f64, bool)>,
    /// `fatigue.life_limit` when saved (the report draws it; a restore takes the
    /// configuration's). Absent from ledgers saved before it was kept.
    #[serde(default)]
    life_limit: Option<f64>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct SavedComponent {
    name: String,
    life_used: f64,
    installed_unix_ms: i64,
    days: Vec<(i64, f64)>,
}

impl FatigueLedger {
    /// Forecast within `horizon_days` from the next bite on (a reload).
    pub(crate) fn set_horizon_days(&mut self, horizon_days: f64) {
        self.horizon_days = horizon_days;
    }

    /// The ledger of `settings`, forecasting within `horizon_days`, begun at
    /// `now_ms` (each component's installation until a reset or a restore says
    /// otherwise); an error for a gate the counter refuses.
    pub(crate) fn new(
        settings: &FatigueSettings,
        horizon_days: f64,
        now_ms: i64,
    ) -> Result<Self, RainflowSettingsError> {
        let counter = Rainflow::new(RainflowSettings {
            gate_knm: settings.gate_knm,
        })?;
        Ok(Self {
            state: counter.state(),
            counter,
            components: settings
                .components
                .iter()
                .map(|c| Account {
                    name: c.name.clone(),
                    curve: c.curve,
                    life_used: 0.0,
                    since_bite: 0.0,
                    installed_unix_ms: now_ms,
                    days: VecDeque::new(),
                })
                .collect(),
            life_limit: settings.life_limit,
            horizon_days,
            untrusted_since_bite: false,
            stream_cuts: 0,
            non_finite_seen: 0,
        })
    }

    /// Count `values` (kN*m), the last taken at `unix_ms`.
    pub(crate) fn samples(&mut self, values: &[f64], unix_ms: i64) {
        let day = unix_ms.div_euclid(MS_PER_DAY);
        let components = &mut self.components;
        self.counter.block(&mut self.state, values, |cycle| {
            add_cycle(components, &cycle, day)
        });
    }

    /// The stream is cut at `unix_ms` (samples lost, saturated, a stale source): the
    /// residue is counted as half cycles and the count starts afresh.
    pub(crate) fn cut(&mut self, unix_ms: i64) {
        let day = unix_ms.div_euclid(MS_PER_DAY);
        let components = &mut self.components;
        self.counter
            .residue(&self.state, |cycle| add_cycle(components, &cycle, day));
        self.state = self.counter.state();
        self.non_finite_seen = 0;
        self.untrusted_since_bite = true;
        self.stream_cuts += 1;
    }

    /// A bite at `unix_ms` (its window `degraded` or not): each component's damage
    /// since the bite before, its life used, rate and forecast.
    pub(crate) fn bite(&mut self, unix_ms: i64, degraded: bool) -> LedgerBite {
        let non_finite = self.state.non_finite();
        let trusted = !degraded && !self.untrusted_since_bite && non_finite == self.non_finite_seen;
        self.non_finite_seen = non_finite;
        self.untrusted_since_bite = false;
        let limits = (self.life_limit, self.horizon_days);
        let components: Vec<ComponentLife> = self
            .components
            .iter_mut()
            .enumerate()
            .map(|(index, account)| {
                let damage = std::mem::take(&mut account.since_bite);
                ComponentLife {
                    name: account.name.clone(),
                    installed_unix_ms: account.installed_unix_ms,
                    figures: account.figures(index, unix_ms, limits, trusted.then_some(damage)),
                }
            })
            .collect();
        LedgerBite {
            worst: worst(&components),
            components,
            stream_cuts: self.stream_cuts,
        }
    }

    /// The published figures at `unix_ms` without a bite (after a reset or a
    /// restore): no bite damage.
    pub(crate) fn figures(&self, unix_ms: i64) -> LedgerBite {
        let limits = (self.life_limit, self.horizon_days);
        let components: Vec<ComponentLife> = self
            .components
            .iter()
            .enumerate()
            .map(|(index, account)| ComponentLife {
                name: account.name.clone(),
                installed_unix_ms: account.installed_unix_ms,
                figures: account.figures(index, unix_ms, limits, None),
            })
            .collect();
        LedgerBite {
            worst: worst(&components),
            components,
            stream_cuts: self.stream_cuts,
        }
    }

    /// Component `index` was replaced at `unix_ms`: its life starts again at 0.
    /// Returns its name and the life it had used; `None` for no such component.
    pub(crate) fn reset(&mut self, index: usize, unix_ms: i64) -> Option<(String, f64)> {
        let account = self.components.get_mut(index)?;
        let used = account.life_used;
        account.life_used = 0.0;
        account.since_bite = 0.0;
        account.installed_unix_ms = unix_ms;
        account.days.clear();
        Some((account.name.clone(), used))
    }

    /// The ledger in its saved form (JSON).
    pub(crate) fn saved(&self) -> String {
        let (residue, pending) = self.state.saved();
        let saved = Saved {
            components: self
                .components
                .iter()
                .map(|c| SavedComponent {
                    name: c.name.clone(),
                    life_used: c.life_used,
                    installed_unix_ms: c.installed_unix_ms,
                    days: c.days.iter().copied().collect(),
                })
                .collect(),
            residue: residue.to_vec(),
            pending,
            life_limit: Some(self.life_limit),
        };
        serde_json::to_string(&saved).unwrap_or_default()
    }

    /// Continue the ledger `text` saved ([`Self::saved`]): each component found by
    /// its name takes its life, installation and days (a component new in the
    /// configuration starts at 0, one no longer configured is dropped), and the
    /// residue is resumed. Returns the components restored; an error for a text
    /// that is not a saved ledger (the ledger is left as it was).
    pub(crate) fn restore(&mut self, text: &str) -> Result<usize, String> {
        let saved: Saved = serde_json::from_str(text).map_err(|error| error.to_string())?;
        let valid = |v: f64| v.is_finite() && v >= 0.0;
        if let Some(bad) = saved
            .components
            .iter()
            .find(|c| !valid(c.life_used) || c.days.iter().any(|(_, d)| !valid(*d)))
        {
            return Err(format!(
                "component \"{}\": a life or damage that is not finite and >= 0",
                bad.name
            ));
        }
        let state = self
            .counter
            .resume(&saved.residue, saved.pending)
            .map_err(|error| format!("the residue: {error}"))?;
        let mut restored = 0;
        for account in &mut self.components {
            if let Some(c) = saved.components.iter().find(|c| c.name == account.name) {
                account.life_used = c.life_used;
                account.installed_unix_ms = c.installed_unix_ms;
                account.days = c.days.iter().copied().collect();
                account.since_bite = 0.0;
                restored += 1;
            }
        }
        self.state = state;
        self.non_finite_seen = 0;
        Ok(restored)
    }
}

/// One component of a saved ledger, as `millgate fatigue --db` prints it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub(crate) struct SavedLife {
    /// Its name.
    pub name: String,
    /// Life used since its installation.
    pub life_used: f64,
    /// Its installation (last reset) or the ledger's start, ms since the epoch.
    pub installed_unix_ms: i64,
}

/// The components of a ledger saved as `text` ([`FatigueLedger::saved`]).
pub(crate) fn saved_lives(text: &str) -> Result<Vec<SavedLife>, serde_json::Error> {
    let saved: Saved = serde_json::from_str(text)?;
    Ok(saved
        .components
        .into_iter()
        .map(|c| SavedLife {
            name: c.name,
            life_used: c.life_used,
            installed_unix_ms: c.installed_unix_ms,
        })
        .collect())
}

/// The `fatigue.life_limit` a ledger saved as `text` was counted against; `None` for
/// a ledger saved before the limit was kept. Read by `millgate report` alone, which
/// the `plot` feature builds.
#[cfg_attr(not(feature = "plot"), allow(dead_code))]
pub(crate) fn saved_life_limit(text: &str) -> Result<Option<f64>, serde_json::Error> {
    Ok(serde_json::from_str::<Saved>(text)?.life_limit)
}

/// Add `cycle`'s damage on `day` to each component.
fn add_cycle(components: &mut [Account], cycle: &Cycle, day: i64) {
    for account in components {
        let damage = account.curve.damage(cycle);
        account.add(damage, day);
    }
}

/// The figures of the component that has used the most of its life (the first of
/// equals).
fn worst(components: &[ComponentLife]) -> FatigueFigures {
    components
        .iter()
        .map(|c| c.figures)
        .reduce(|worst, c| {
            if c.life_used > worst.life_used {
                c
            } else {
                worst
            }
        })
        .unwrap_or(FatigueFigures {
            component: 0,
            life_used: 0.0,
            bite_damage: None,
            rate_per_day: None,
            forecast: ForecastState::TooFewBites,
            days_to_limit: None,
            limit_date_unix_ms: None,
        })
}

#[cfg(test)]
mod tests {
    use super::*;
    use millgate_config::FatigueComponent;
    use millgate_dsp::miner::{EnduranceRule, MeanCorrection, SnCurveSettings};

    const DAY: i64 = MS_PER_DAY;

    fn settings(gate_knm: f64) -> FatigueSettings {
        let curve = |m, share| {
            SnCurve::new(SnCurveSettings {
                m,
                // Short lives: a few bars use a few percent of them.
                ref_cycles: 100.0,
                ref_range_knm: 100.0,
                torque_share: share,
                endurance_knm: None,
                endurance_rule: EnduranceRule::Cutoff,
                mean_correction: MeanCorrection::None,
            })
            .unwrap()
        };
        FatigueSettings {
            gate_knm,
            life_limit: 0.8,
            components: vec![
                FatigueComponent {
                    name: "spindle".into(),
                    curve: curve(5.0, 0.5),
                },
                FatigueComponent {
                    name: "coupling".into(),
                    curve: curve(3.0, 1.0),
                },
            ],
        }
    }

    /// Bars: idle at 0, a ring-down from 150 to 100 kN*m, exit; `bars` of them.
    fn bars(bars: usize) -> Vec<f64> {
        let mut samples = Vec::new();
        for bar in 0..bars {
            samples.extend([0.0; 20]);
            for i in 0..200 {
                let t = i as f64 / 20.0;
                let ring = 50.0 * (-0.3 * t).exp() * (std::f64::consts::TAU * t).cos();
                samples.push(100.0 + ring + bar as f64 * 0.1);
            }
        }
        samples.extend([0.0; 20]);
        samples
    }

    #[test]
    fn the_stream_s_damage_is_that_of_the_offline_account_whatever_the_blocks() {
        let samples = bars(5);
        let settings = settings(1.0);
        let curves: Vec<SnCurve> = settings.components.iter().map(|c| c.curve).collect();
        let mut one = |each: &mut dyn FnMut(&[f64])| -> Result<(), RainflowSettingsError> {
            each(&samples);
            Ok(())
        };
        let offline = super::super::fatigue::account(1.0, &curves, &mut one).unwrap();
        let mut ledger = FatigueLedger::new(&settings, 365.0, 0).unwrap();
        let mut bite_damage = [0.0; 2];
        for (k, block) in samples.chunks(37).enumerate() {
            ledger.samples(block, 1000 * k as i64);
            if k % 5 == 4 {
                let bite = ledger.bite(1000 * k as i64, false);
                for (sum, c) in bite_damage.iter_mut().zip(&bite.components) {
                    *sum += c.figures.bite_damage.unwrap();
                }
            }
        }
        // The offline account ends the record: closes the residue as half cycles.
        ledger.cut(100_000);
        let end = ledger.bite(100_000, false);
        for (i, component) in end.components.iter().enumerate() {
            let offline = offline.damage[i];
            assert!(offline > 0.0);
            assert!(
                (component.figures.life_used - offline).abs() <= 1e-12 * offline,
                "{} vs {offline}",
                component.figures.life_used
            );
            // The bites' damage adds up to the life used before the cut.
            assert!(bite_damage[i] <= component.figures.life_used);
        }
        // After a cut the bite's damage cannot be trusted: no value, counted.
        assert_eq!(end.worst.bite_damage, None);
        assert_eq!(end.stream_cuts, 1);
        assert!(ledger.bite(100_000, false).worst.bite_damage.is_some());
    }

    #[test]
    fn a_saved_ledger_continues_as_if_never_stopped() {
        let samples = bars(4);
        let (head, tail) = samples.split_at(517);
        let mut whole = FatigueLedger::new(&settings(1.0), 365.0, 0).unwrap();
        whole.samples(&samples, DAY);
        let mut first = FatigueLedger::new(&settings(1.0), 365.0, 0).unwrap();
        first.samples(head, DAY);
        let saved = first.saved();
        let mut second = FatigueLedger::new(&settings(1.0), 365.0, 5 * DAY).unwrap();
        assert_eq!(second.restore(&saved), Ok(2));
        second.samples(tail, DAY);
        let (a, b) = (whole.figures(2 * DAY), second.figures(2 * DAY));
        assert_eq!(a.components, b.components);
        assert!(second.restore("{\"components\": 3}").is_err());
        let bad = saved.replacen("\"life_used\":", "\"life_used\":-", 1);
        assert!(second.restore(&bad).is_err(), "{bad}");
        assert_eq!(saved_life_limit(&saved).unwrap(), Some(0.8));
        let old = saved.replace(",\"life_limit\":0.8", "");
        assert_ne!(old, saved);
        assert_eq!(saved_life_limit(&old).unwrap(), None);
        assert_eq!(
            second.restore(&old),
            Ok(2),
            "a ledger saved without its limit"
        );
    }

    #[test]
    fn rate_and_forecast_states() {
        let mut ledger = FatigueLedger::new(&settings(1.0), 365.0, 0).unwrap();
        // Under a day counted: no rate.
        ledger.samples(&bars(2), DAY / 2);
        let early = ledger.figures(DAY / 2).worst;
        assert_eq!(early.forecast, ForecastState::TooFewBites);
        assert_eq!(early.rate_per_day, None);
        // Three days later, nothing more: the rate is the damage over 3.5 days.
        let later = ledger.figures(3 * DAY + DAY / 2);
        let worst = later.worst;
        let used = worst.life_used;
        let rate = worst.rate_per_day.unwrap();
        assert!((rate - used / 3.5).abs() < 1e-12 * rate);
        assert_eq!(worst.forecast, ForecastState::Forecast);
        let days = worst.days_to_limit.unwrap();
        assert!((days - (0.8 - used) / rate).abs() < 1e-6 * days);
        // The worst component is the one with the most life used.
        let most = later
            .components
            .iter()
            .map(|c| c.figures.life_used)
            .fold(0.0, f64::max);
        assert_eq!(worst.life_used, most);
        // Past the rate's window without damage: not consuming.
        let quiet = ledger.figures(30 * DAY).worst;
        assert_eq!(quiet.forecast, ForecastState::NotGrowing);
        assert_eq!(quiet.rate_per_day, Some(0.0));
        // Beyond the horizon: a horizon of a moment.
        let mut short = FatigueLedger::new(&settings(1.0), 1e-9, 0).unwrap();
        short.samples(&bars(2), DAY / 2);
        assert_eq!(
            short.figures(2 * DAY).worst.forecast,
            ForecastState::BeyondHorizon
        );
    }

    #[test]
    fn a_reset_starts_one_component_at_zero() {
        let mut ledger = FatigueLedger::new(&settings(1.0), 365.0, 0).unwrap();
        ledger.samples(&bars(3), DAY);
        let before = ledger.figures(DAY);
        let (name, used) = ledger.reset(1, 2 * DAY).unwrap();
        assert_eq!(name, "coupling");
        assert_eq!(used, before.components[1].figures.life_used);
        let after = ledger.figures(2 * DAY);
        assert_eq!(after.components[1].figures.life_used, 0.0);
        assert_eq!(after.components[1].installed_unix_ms, 2 * DAY);
        assert_eq!(
            after.components[0].figures.life_used,
            before.components[0].figures.life_used
        );
        assert_eq!(ledger.reset(2, 2 * DAY), None);
    }

    #[test]
    fn non_finite_samples_make_the_bite_s_damage_untrusted() {
        let mut ledger = FatigueLedger::new(&settings(1.0), 365.0, 0).unwrap();
        ledger.samples(&bars(1), DAY);
        assert!(ledger.bite(DAY, false).worst.bite_damage.is_some());
        ledger.samples(&[f64::NAN, 1.0], DAY);
        assert_eq!(ledger.bite(DAY, false).worst.bite_damage, None);
        ledger.samples(&bars(1), DAY);
        assert!(ledger.bite(DAY, false).worst.bite_damage.is_some());
        assert_eq!(ledger.bite(DAY, true).worst.bite_damage, None, "degraded");
    }
}
