//! The finishing speeds to avoid: each source's unstable speed bands over the
//! configuration's range, and their union per pass.

use millgate_dsp::mathieu::MAX_ORDER;

use super::setup::{AvoidBand, PassSetup};
use super::sources::{Source, SourceSetup, SpanSetup};
use crate::rod::RodError;

/// Grid speeds per configuration range in the band search (plus the tongue centres).
const GRID: usize = 200;

/// Bisection steps refining a band edge (2^-40 of the range).
const EDGE_STEPS: usize = 40;

impl PassSetup {
    /// Every source's unstable speed bands.
    pub(super) fn find_bands(&mut self) -> Result<(), RodError> {
        for s in 0..self.spans.len() {
            for k in 0..self.spans[s].sources.len() {
                let bands = self.bands(&self.spans[s], &self.spans[s].sources[k])?;
                self.spans[s].sources[k].bands = bands;
            }
        }
        Ok(())
    }

    /// The unstable finishing-speed intervals of one source over the speed range.
    fn bands(&self, span: &SpanSetup, source: &SourceSetup) -> Result<Vec<(f64, f64)>, RodError> {
        let (lo, hi) = self.speed_range_m_s;
        let moves =
            self.mill.rod.moving_rod || matches!(source.source, Source::Eccentricity { .. });
        if !moves {
            return Ok(if self.unstable(span, source, lo)? {
                vec![(lo, hi)]
            } else {
                Vec::new()
            });
        }
        let mut speeds: Vec<f64> = (0..=GRID)
            .map(|k| lo + (hi - lo) * k as f64 / GRID as f64)
            .collect();
        // a - c^2 = a (1 - zeta^2) falls with speed: bisect for each tongue centre n^2.
        let shrink = 1.0 - self.mill.rod.damping_ratio.powi(2);
        let shifted = |v: f64| self.operating(span, source, v).a * shrink;
        for n in 1..=MAX_ORDER {
            let target = f64::from(n * n);
            if shifted(lo) < target || shifted(hi) > target {
                continue;
            }
            let (mut left, mut right) = (lo, hi);
            for _ in 0..EDGE_STEPS {
                let middle = 0.5 * (left + right);
                if shifted(middle) > target {
                    left = middle;
                } else {
                    right = middle;
                }
            }
            speeds.push(0.5 * (left + right));
        }
        speeds.sort_by(f64::total_cmp);
        let mut states = Vec::with_capacity(speeds.len());
        for &v in &speeds {
            states.push(self.unstable(span, source, v)?);
        }
        let mut bands = Vec::new();
        let mut start = states[0].then_some(lo);
        for i in 1..speeds.len() {
            if states[i] == states[i - 1] {
                continue;
            }
            // Bisect the change between speeds[i - 1] and speeds[i].
            let (mut left, mut right) = (speeds[i - 1], speeds[i]);
            for _ in 0..EDGE_STEPS {
                if right - left <= 1e-9 * (hi - lo) {
                    break;
                }
                let middle = 0.5 * (left + right);
                if self.unstable(span, source, middle)? == states[i - 1] {
                    left = middle;
                } else {
                    right = middle;
                }
            }
            let edge = 0.5 * (left + right);
            match start.take() {
                Some(from) => bands.push((from, edge)),
                None => start = Some(edge),
            }
        }
        if let Some(from) = start {
            bands.push((from, hi));
        }
        Ok(bands)
    }

    /// Union of the sources' bands, labelled, leaving out the sources unstable over
    /// the whole range.
    pub(super) fn merged_bands(&self) -> Vec<AvoidBand> {
        let mut all: Vec<(f64, f64, String)> = Vec::new();
        for span in &self.spans {
            for source in &span.sources {
                if source.bands == [self.speed_range_m_s] {
                    continue;
                }
                for &(from, to) in &source.bands {
                    all.push((from, to, self.describe(span, source)));
                }
            }
        }
        all.sort_by(|x, y| x.0.total_cmp(&y.0));
        let mut merged: Vec<AvoidBand> = Vec::new();
        for (from, to, label) in all {
            match merged.last_mut() {
                Some(last) if from <= last.to_m_s => {
                    last.to_m_s = last.to_m_s.max(to);
                    if !last.sources.contains(&label) {
                        last.sources.push(label);
                    }
                }
                _ => merged.push(AvoidBand {
                    from_m_s: from,
                    to_m_s: to,
                    sources: vec![label],
                }),
            }
        }
        merged
    }

    /// `span / mode / source` of every point unstable over the whole speed range.
    pub(super) fn unstable_everywhere(&self) -> Vec<String> {
        self.spans
            .iter()
            .flat_map(|span| span.sources.iter().map(move |source| (span, source)))
            .filter(|(_, source)| source.bands == [self.speed_range_m_s])
            .map(|(span, source)| self.describe(span, source))
            .collect()
    }
}
