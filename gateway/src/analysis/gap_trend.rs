//! The wear trend of a driveline's gap: every bite since the last wear reset folded, in
//! time order, into a filter of the gap and its growth per coupling hypothesis
//! ([`millgate_dsp::wear_trend`]), and the forecast of when the gap reaches its alarm.
//!
//! - **Per bite**: the bite's log-likelihood over the gap of each coupling in the maps
//!   (noise and interpolation error only: [`Allowance::Trend`]) on the grid the filter
//!   asks for (a local one around its prediction once that is narrow, else the maps'
//!   fine grid), folded into that coupling's filter; the model floor (what the whole
//!   allowance adds to one bite's variance) is measured on the likeliest coupling and
//!   carried beside the filter, on every published interval.
//! - **Time** is the bite's, in calendar days: shifts, weekends, outages and restarts
//!   only lengthen the step between two bites. A bite dated before the last one (a
//!   clock stepped back) is folded in at the last one's time.
//! - **Saved form** (`SavedTrend`, JSON): the filter's state as plain numbers, which the
//!   history keeps with the driveline's state so a restart continues the trend.

use millgate_dsp::wear_trend::{
    BiteMoments, Forecast, ForecastReason, Hypothesis, Phase, TrendError, TrendEstimate, WearTrend,
    WearTrendState, MAX_COUPLINGS,
};
use serde::{Deserialize, Serialize};

use super::gap_estimate::{
    estimate_of, fine_grid, fine_logliks, loglik_at, Allowance, GapEstimate, GapObservation,
};
use crate::state::gap_maps::GapMaps;
use crate::state::results::{
    ConePoint, ForecastState, GapCone, GapForecast, GapGrowth, GapResults, CONE_POINTS,
};

/// Fewest bites since the last wear reset for a trend and a forecast.
pub const MIN_TREND_BITES: u32 = millgate_dsp::wear_trend::MIN_BITES;

/// A trend whose growth is not [`EARLY_GROWTH_SD`] standard deviations clear of 0
/// forecasts nothing before its bites span this many days.
pub const MIN_TREND_SPAN_DAYS: f64 = 7.0;

/// Standard deviations by which a trend shorter than [`MIN_TREND_SPAN_DAYS`] must
/// show its growth clear of 0 to forecast (one-sided 0.13% by chance on a stable gap).
pub const EARLY_GROWTH_SD: f64 = 3.0;

/// How far back the fitted growth line is drawn at most, days.
const CONE_BACK_DAYS: f64 = 28.0;

/// Milliseconds per day.
const MS_PER_DAY: f64 = 86_400_000.0;

/// A driveline's wear trend: the filter's coefficients and state, and the model
/// coupling index of each hypothesis (the maps' order).
#[derive(Debug, Clone)]
pub struct GapTrend {
    trend: WearTrend,
    state: WearTrendState,
    /// The model coupling of hypothesis k; empty until the maps are known.
    couplings: Vec<usize>,
    /// The fingerprint of the maps the bites were folded against.
    maps: Option<u64>,
    /// Time of the first bite folded in since the last reset, ms since the Unix epoch.
    first_bite_unix_ms: Option<i64>,
    /// Time of the last bite folded in, ms since the Unix epoch.
    last_bite_unix_ms: Option<i64>,
}

/// What one bite did to the trend.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Folded {
    /// Folded in.
    Folded {
        /// The gap stepped (every hypothesis was reopened): a coupling changed without
        /// a wear reset, a re-mounted sensor, another model.
        jumped: bool,
        /// The bite's own estimate (its whole allowance, from the likelihood the fold
        /// computed anyway for the model floor); `None` for a Gaussian observation.
        bite: Option<GapEstimate>,
    },
    /// Outside the maps' static torque range: not folded in.
    OutsideMaps,
}

impl GapTrend {
    /// An empty trend forecasting up to `horizon_days`.
    pub fn new(horizon_days: f64) -> Result<Self, TrendError> {
        let trend = WearTrend::new(horizon_days)?;
        Ok(Self {
            state: trend.state(0)?,
            trend,
            couplings: Vec::new(),
            maps: None,
            first_bite_unix_ms: None,
            last_bite_unix_ms: None,
        })
    }

    /// Take the bites within `seconds` of the trend's first (or of a jump) as one gap,
    /// its growth from bites further apart (`wear.growth_span_s`; see
    /// [`WearTrend::set_growth_span_days`]). On an error the span is unchanged.
    pub fn set_growth_span_s(&mut self, seconds: f64) -> Result<(), TrendError> {
        self.trend.set_growth_span_days(seconds / 86_400.0)
    }

    /// Forecast up to `horizon_days` from the next forecast on (a reload); the bites
    /// folded in are kept. On an error the horizon is unchanged.
    pub fn set_horizon_days(&mut self, horizon_days: f64) -> Result<(), TrendError> {
        self.trend.set_horizon_days(horizon_days)
    }

    /// Forget every bite (a wear reset: the coupling was replaced).
    pub fn reset(&mut self) {
        // At most MAX_COUPLINGS hypotheses (`fold` keeps no more): the reset holds.
        self.state = self.trend.state(self.couplings.len()).unwrap_or(self.state);
        self.first_bite_unix_ms = None;
        self.last_bite_unix_ms = None;
    }

    /// Fold in the bite `observation` made at `unix_ms` against `maps`.
    pub fn fold(
        &mut self,
        maps: &GapMaps,
        observation: &GapObservation,
        unix_ms: i64,
    ) -> Result<Folded, TrendError> {
        let couplings: Vec<usize> = maps
            .maps()
            .iter()
            .map(|map| map.coupling)
            .take(MAX_COUPLINGS)
            .collect();
        if self.maps != Some(maps.fingerprint()) || couplings != self.couplings {
            // Other maps (another model, other settings): bites folded against the old
            // ones do not compare with the next; the trend starts again.
            if self.state.bites > 0 {
                tracing::warn!(
                    bites = self.state.bites,
                    "the gap maps changed (another model or settings): the wear trend starts again"
                );
            }
            self.couplings = couplings;
            self.maps = Some(maps.fingerprint());
            self.reset();
        }
        let Some([noise, whole]) =
            fine_logliks(maps, observation, [Allowance::Trend, Allowance::Whole])
        else {
            return Ok(Folded::OutsideMaps);
        };
        let fine = fine_grid(maps);
        // A bite dated before the last one (the clock stepped back, or bites dated
        // from when their blocks were handled came out of order) is folded in at the
        // last one's time: nothing is lost, and the trend's time never runs backwards.
        let unix_ms = unix_ms.max(self.last_bite_unix_ms.unwrap_or(i64::MIN));
        let time = unix_ms as f64 / MS_PER_DAY;
        self.trend.predict(&mut self.state, time)?;
        let likeliest = self
            .trend
            .estimate(&self.state)
            .map_or(0, |estimate| estimate.likeliest);
        let mut local = vec![0.0; fine.len];
        let mut jumped = false;
        let mut likeliest_noise = None;
        for (k, loglik) in noise.iter().enumerate().take(self.couplings.len()) {
            let bite = BiteMoments::from_loglik(fine, loglik)?;
            if k == likeliest {
                likeliest_noise = Some(bite);
            }
            let grid = self.trend.grid(&self.state, k, fine);
            let values = if grid == fine {
                loglik.as_slice()
            } else {
                local.resize(grid.len, 0.0);
                loglik_at(maps, k, observation, grid, Allowance::Trend, &mut local);
                &local[..grid.len]
            };
            jumped |= self
                .trend
                .update(&mut self.state, k, grid, values, bite)?
                .jumped;
        }
        // The model floor in gap units: what the whole allowance adds to the bite's
        // variance on the likeliest coupling.
        let floor2 = match whole.get(likeliest) {
            Some(whole) => {
                let noise = match likeliest_noise {
                    Some(noise) => noise,
                    None => BiteMoments::from_loglik(fine, &noise[likeliest])?,
                };
                let whole = BiteMoments::from_loglik(fine, whole)?;
                Some((whole.var_mrad2 - noise.var_mrad2).max(0.0))
            }
            None => None,
        };
        self.trend.finish_bite(&mut self.state, floor2);
        self.first_bite_unix_ms.get_or_insert(unix_ms);
        self.last_bite_unix_ms = Some(unix_ms);
        Ok(Folded::Folded {
            jumped,
            bite: estimate_of(maps, &whole),
        })
    }

    /// Fold in a bite whose gap was measured elsewhere, as a Gaussian (mean mrad,
    /// variance mrad^2) for the single coupling `coupling`: a history fixture or a
    /// record diagnosed by another tool. The model floor is taken as 0.
    pub fn fold_gaussian(
        &mut self,
        coupling: usize,
        (mean_mrad, var_mrad2): (f64, f64),
        unix_ms: i64,
    ) -> Result<Folded, TrendError> {
        if self.couplings != [coupling] || self.maps.is_some() {
            self.couplings = vec![coupling];
            self.maps = None;
            self.reset();
        }
        let unix_ms = unix_ms.max(self.last_bite_unix_ms.unwrap_or(i64::MIN));
        self.trend
            .predict(&mut self.state, unix_ms as f64 / MS_PER_DAY)?;
        let outcome = self
            .trend
            .update_gaussian(&mut self.state, 0, mean_mrad, var_mrad2)?;
        self.trend.finish_bite(&mut self.state, None);
        self.first_bite_unix_ms.get_or_insert(unix_ms);
        self.last_bite_unix_ms = Some(unix_ms);
        Ok(Folded::Folded {
            jumped: outcome.jumped,
            bite: None,
        })
    }

    /// The trend's estimate: the gap at the last bite, its growth and the forecast of
    /// reaching `alarm_mrad`; `None` before the first bite.
    pub fn results(&self, alarm_mrad: f64) -> Option<GapResults> {
        let estimate = self.trend.estimate(&self.state)?;
        let coupling_of = |k: usize| self.couplings.get(k).copied();
        let forecast = self.trend.forecast(&self.state, alarm_mrad);
        Some(GapResults {
            gap_mrad: estimate.gap_mrad,
            low_mrad: estimate.gap_low_mrad,
            high_mrad: estimate.gap_high_mrad,
            coupling: estimate.coupling.and_then(coupling_of),
            likeliest_coupling: coupling_of(estimate.likeliest),
            bites_pooled: estimate.bites as usize,
            growth: growth(&estimate),
            forecast: self.published(&forecast, &estimate),
        })
    }

    /// `forecast` as published, dated from the last bite, with its cone. A trend of
    /// less than [`MIN_TREND_SPAN_DAYS`] whose growth is not [`EARLY_GROWTH_SD`]
    /// standard deviations clear of 0 has too few bites: its early end would only say
    /// how little is known yet, and a 90% interval clear of 0 by chance (one bite in
    /// twenty on a stable gap) would forecast a growth that is not there (after every
    /// wear reset, a near alarm to a PLC that acts on it).
    fn published(&self, forecast: &Forecast, estimate: &TrendEstimate) -> Option<GapForecast> {
        let span_days = self
            .first_bite_unix_ms
            .zip(self.last_bite_unix_ms)
            .map_or(0.0, |(first, last)| (last - first) as f64 / MS_PER_DAY);
        let forecasting = matches!(
            forecast.reason,
            ForecastReason::Forecast | ForecastReason::NotGrowing | ForecastReason::BeyondHorizon
        );
        if forecasting && span_days < MIN_TREND_SPAN_DAYS && !growth_clear(estimate) {
            let too_few = Forecast {
                reason: ForecastReason::TooFewBites,
                days: None,
                days_low: None,
                days_high: None,
            };
            return self.published(&too_few, estimate);
        }
        let state = match forecast.reason {
            ForecastReason::Forecast => ForecastState::Forecast,
            ForecastReason::AtAlarm => ForecastState::AtAlarm,
            ForecastReason::NotGrowing => ForecastState::NotGrowing,
            ForecastReason::BeyondHorizon => ForecastState::BeyondHorizon,
            ForecastReason::TooFewBites => ForecastState::TooFewBites,
            ForecastReason::NoEstimate => return None,
        };
        let date_unix_ms = self
            .last_bite_unix_ms
            .zip(forecast.days)
            .map(|(last, days)| last + (days * MS_PER_DAY).round() as i64);
        Some(GapForecast {
            state,
            days: forecast.days,
            days_low: forecast.days_low,
            days_high: forecast.days_high,
            date_unix_ms,
            cone: self.cone(forecast, estimate),
        })
    }

    /// The cone of `forecast`: the band from the last bite to a quarter beyond its
    /// late end (the horizon when it has none), and how far back the fitted growth
    /// line goes; `None` without a growth.
    fn cone(&self, forecast: &Forecast, estimate: &TrendEstimate) -> Option<GapCone> {
        estimate.rate_mrad_per_day?;
        let horizon = self.trend.horizon_days();
        let end = forecast
            .days_high
            .or(forecast.days)
            .or(forecast.days_low)
            .map_or(horizon, |days| {
                (1.25 * days).clamp(f64::MIN_POSITIVE, horizon)
            });
        let mut points = [ConePoint::default(); CONE_POINTS];
        for (k, point) in points.iter_mut().enumerate() {
            let days = end * k as f64 / (CONE_POINTS - 1) as f64;
            let band = self.trend.band(&self.state, days)?;
            *point = ConePoint {
                days,
                mean_mrad: band.mean_mrad,
                low_mrad: band.low_mrad,
                high_mrad: band.high_mrad,
            };
        }
        let since_first = self
            .first_bite_unix_ms
            .zip(self.last_bite_unix_ms)
            .map_or(0.0, |(first, last)| (last - first) as f64 / MS_PER_DAY);
        Some(GapCone {
            points,
            back_days: since_first.min(CONE_BACK_DAYS),
        })
    }

    /// Time of the last bite folded in, ms since the Unix epoch.
    pub fn last_bite_unix_ms(&self) -> Option<i64> {
        self.last_bite_unix_ms
    }

    /// The saved form (JSON).
    pub fn saved(&self) -> String {
        let saved = SavedTrend {
            version: SAVED_VERSION,
            couplings: self.couplings.clone(),
            maps: self.maps.map(|fingerprint| format!("{fingerprint:016x}")),
            first_bite_unix_ms: self.first_bite_unix_ms,
            last_bite_unix_ms: self.last_bite_unix_ms,
            t_last_days: self.state.t_last_days,
            bites: self.state.bites,
            floor2_mrad2: self.state.floor2_mrad2,
            floor_measured: self.state.floor_measured,
            hypotheses: self.state.hypotheses[..self.state.couplings]
                .iter()
                .map(SavedHypothesis::from)
                .collect(),
        };
        serde_json::to_string(&saved).unwrap_or_default()
    }

    /// The trend saved as `text` ([`Self::saved`]), forecasting up to `horizon_days`.
    pub fn restored(horizon_days: f64, text: &str) -> Result<Self, RestoreError> {
        let mut trend = Self::new(horizon_days)?;
        trend.restore(text)?;
        Ok(trend)
    }

    /// Continue the trend saved as `text` ([`Self::saved`]).
    pub fn restore(&mut self, text: &str) -> Result<(), RestoreError> {
        let saved: SavedTrend = serde_json::from_str(text)?;
        if saved.version != SAVED_VERSION {
            return Err(RestoreError::Version(saved.version));
        }
        let couplings = saved.hypotheses.len();
        if couplings != saved.couplings.len() || couplings > MAX_COUPLINGS {
            return Err(RestoreError::Couplings(couplings));
        }
        let mut state = self.trend.state(couplings)?;
        for (slot, hypothesis) in state.hypotheses.iter_mut().zip(&saved.hypotheses) {
            *slot = hypothesis.to_dsp()?;
        }
        state.t_last_days = saved.t_last_days;
        state.bites = saved.bites;
        state.floor2_mrad2 = saved.floor2_mrad2;
        state.floor_measured = saved.floor_measured;
        let maps = match saved.maps {
            Some(text) => {
                Some(u64::from_str_radix(&text, 16).map_err(|_| RestoreError::Maps(text.clone()))?)
            }
            None => None,
        };
        self.state = state;
        self.couplings = saved.couplings;
        self.maps = maps;
        self.first_bite_unix_ms = saved.first_bite_unix_ms;
        self.last_bite_unix_ms = saved.last_bite_unix_ms;
        Ok(())
    }
}

/// Whether `estimate`'s growth is [`EARLY_GROWTH_SD`] standard deviations above 0.
fn growth_clear(estimate: &TrendEstimate) -> bool {
    match (
        estimate.rate_mrad_per_day,
        estimate.rate_low_mrad_per_day,
        estimate.rate_high_mrad_per_day,
    ) {
        (Some(rate), Some(low), Some(high)) => {
            let sd = (high - low) / (2.0 * millgate_dsp::wear_trend::Z90);
            rate > EARLY_GROWTH_SD * sd
        }
        _ => false,
    }
}

/// The growth of `estimate`, once it has one.
fn growth(estimate: &TrendEstimate) -> Option<GapGrowth> {
    Some(GapGrowth {
        mrad_per_day: estimate.rate_mrad_per_day?,
        low_mrad_per_day: estimate.rate_low_mrad_per_day?,
        high_mrad_per_day: estimate.rate_high_mrad_per_day?,
    })
}

/// Format of [`SavedTrend`].
const SAVED_VERSION: u32 = 1;

/// Why a saved trend cannot be continued.
#[derive(Debug, thiserror::Error)]
pub enum RestoreError {
    /// Not the JSON of a saved trend.
    #[error("not a saved wear trend: {0}")]
    Json(#[from] serde_json::Error),
    /// Another format.
    #[error("saved wear trend format {0}, this millgate reads {SAVED_VERSION}")]
    Version(u32),
    /// More hypotheses than couplings named, or than a trend holds.
    #[error("saved wear trend with {0} hypotheses for its couplings")]
    Couplings(usize),
    /// The maps' fingerprint is not one.
    #[error("saved wear trend with maps fingerprint {0:?}")]
    Maps(String),
    /// The filter refused the state.
    #[error("saved wear trend refused: {0}")]
    Trend(#[from] TrendError),
}

/// The saved form of a [`GapTrend`]: what a restart needs to continue it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct SavedTrend {
    /// Format ([`SAVED_VERSION`]).
    version: u32,
    /// The model coupling of each hypothesis.
    couplings: Vec<usize>,
    /// The maps' fingerprint (hex), `None` for Gaussian observations.
    maps: Option<String>,
    /// Time of the first bite since the last reset, ms since the Unix epoch.
    first_bite_unix_ms: Option<i64>,
    /// Time of the last bite, ms since the Unix epoch.
    last_bite_unix_ms: Option<i64>,
    /// The filter's time of the last bite, days.
    t_last_days: Option<f64>,
    /// Bites since the reset.
    bites: u32,
    /// The model floor, mrad^2.
    floor2_mrad2: f64,
    /// Whether the floor was measured.
    floor_measured: bool,
    /// One per coupling.
    hypotheses: Vec<SavedHypothesis>,
}

/// A [`Hypothesis`] as saved.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct SavedHypothesis {
    gap_mrad: f64,
    rate_mrad_per_day: f64,
    p: [[f64; 2]; 2],
    loglik: f64,
    scale: f64,
    /// `empty`, `gap_only` or `tracking`.
    phase: String,
    time_days: f64,
    outlier_run: u32,
}

impl From<&Hypothesis> for SavedHypothesis {
    fn from(h: &Hypothesis) -> Self {
        let phase = match h.phase {
            Phase::Empty => "empty",
            Phase::GapOnly => "gap_only",
            Phase::Tracking => "tracking",
        };
        Self {
            gap_mrad: h.gap_mrad,
            rate_mrad_per_day: h.rate_mrad_per_day,
            p: h.p,
            loglik: h.loglik,
            scale: h.scale,
            phase: phase.to_owned(),
            time_days: h.time_days,
            outlier_run: h.outlier_run,
        }
    }
}

impl SavedHypothesis {
    fn to_dsp(&self) -> Result<Hypothesis, RestoreError> {
        let phase = match self.phase.as_str() {
            "empty" => Phase::Empty,
            "gap_only" => Phase::GapOnly,
            "tracking" => Phase::Tracking,
            _ => return Err(RestoreError::Trend(TrendError::Observation)),
        };
        let numbers = [
            self.gap_mrad,
            self.rate_mrad_per_day,
            self.p[0][0],
            self.p[0][1],
            self.p[1][0],
            self.p[1][1],
            self.loglik,
            self.scale,
            self.time_days,
        ];
        if !numbers.iter().all(|v| v.is_finite()) {
            return Err(RestoreError::Trend(TrendError::NotFinite));
        }
        Ok(Hypothesis {
            gap_mrad: self.gap_mrad,
            rate_mrad_per_day: self.rate_mrad_per_day,
            p: self.p,
            loglik: self.loglik,
            scale: self.scale,
            phase,
            time_days: self.time_days,
            outlier_run: self.outlier_run,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_new_horizon_applies_to_the_next_forecast_and_keeps_the_bites() {
        let mut trend = GapTrend::new(365.0).unwrap();
        // 60 days of daily bites on a gap opening 0.02 mrad a day from 1 mrad: the
        // alarm at 4 mrad is about 90 days past the last bite.
        for day in 0..60 {
            let gap = 1.0 + 0.02 * f64::from(day);
            let ms = i64::from(day) * MS_PER_DAY as i64;
            trend.fold_gaussian(0, (gap, 0.01), ms).unwrap();
        }
        let forecast = |trend: &GapTrend| trend.results(4.0).unwrap().forecast.unwrap();
        let year = forecast(&trend);
        assert_eq!(year.state, ForecastState::Forecast, "{year:?}");
        let days = year.days.unwrap();
        assert!((60.0..120.0).contains(&days), "{days}");

        trend.set_horizon_days(30.0).unwrap();
        let month = forecast(&trend);
        assert_eq!(month.state, ForecastState::BeyondHorizon, "{month:?}");
        assert_eq!(month.days, None);
        assert!(trend.set_horizon_days(0.0).is_err());
        trend.set_horizon_days(365.0).unwrap();
        assert_eq!(forecast(&trend), year, "the bites are kept");
    }
}
