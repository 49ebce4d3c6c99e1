//! A pass at one finishing speed: every operating point with its tongue and margins
//! ([`PassSetup::evaluate`]), or only each span's stability ([`PassSetup::status`]).

use std::f64::consts::PI;

use serde::Serialize;

use super::setup::{AvoidBand, PassSetup};
use super::sources::Source;
use crate::rod::RodError;

/// One operating point at one finishing speed.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PointReport {
    /// Rod bending mode, 1-based.
    pub mode: usize,
    /// Source label.
    pub source: String,
    /// The source itself.
    pub(crate) excitation: Source,
    /// Rod natural frequency of this mode, Hz.
    pub f_rod_hz: f64,
    /// Pulsation frequency Theta, Hz.
    pub theta_hz: f64,
    /// Mathieu a = 4 omega^2 / Theta^2.
    pub(crate) a: f64,
    /// Mathieu q = 2 g P / (L^2 rho A Theta^2).
    pub q: f64,
    /// Damping c = zeta sqrt(a), per unit Mathieu time.
    pub(crate) c: f64,
    /// Order of the nearest damped tongue (`None` beyond the resolved range).
    pub(crate) tongue: Option<u8>,
    /// Inside it.
    pub(crate) inside: Option<bool>,
    /// Growth exponent, 1/s (negative: decays); `None` beyond the resolved range.
    pub exponent_per_s: Option<f64>,
    /// Stable (exponent <= 0).
    pub stable: bool,
    /// Signed distance in a to the nearest damped tongue edge (> 0 stable).
    pub(crate) margin_a: Option<f64>,
    /// Finishing-speed change to the nearest band edge of this point, m/s (`None`:
    /// no band within the speed range).
    pub speed_change_m_s: Option<f64>,
}

/// One span at one finishing speed.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SpanReport {
    /// `upstream - downstream`.
    pub span: String,
    /// Rod diameter in the span, mm.
    pub(crate) diameter_mm: f64,
    /// Rod speed in the span, m/s.
    pub(crate) rod_speed_m_s: f64,
    /// Rod speed over the span's critical speed (reported whether or not the moving-rod
    /// term is on).
    pub v_over_v_crit: f64,
    /// Euler load of the span, N.
    pub(crate) euler_load_n: f64,
    /// Every mode and source.
    pub points: Vec<PointReport>,
    /// No point is unstable.
    pub stable: bool,
}

/// One pass at one finishing speed.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PassReport {
    /// Pass name.
    pub(crate) pass: String,
    /// Configuration name.
    pub(crate) configuration: String,
    /// Finishing speed evaluated, m/s.
    pub(crate) finishing_speed_m_s: f64,
    /// The configuration's finishing-speed range, m/s.
    pub(crate) speed_range_m_s: (f64, f64),
    /// Rod temperature, deg C.
    pub(crate) temperature_c: f64,
    /// Young's modulus at it, Pa.
    pub(crate) modulus_pa: f64,
    /// Every span.
    pub spans: Vec<SpanReport>,
    /// No point of any span is unstable.
    pub(crate) stable: bool,
    /// Largest growth exponent of any point, 1/s.
    pub(crate) worst_exponent_per_s: Option<f64>,
    /// Finishing speeds to avoid in this pass's geometry, m/s.
    pub(crate) avoid: Vec<AvoidBand>,
    /// Points unstable at every speed of the range (no speed change helps).
    pub(crate) unstable_at_every_speed: Vec<String>,
}

impl PassSetup {
    /// Each span's stability, worst exponent and speed margin at finishing speed
    /// `speed_m_s` (> 0): the exponents and the precomputed bands only, no tongue
    /// search (microseconds per pass when the points are in stable gaps).
    pub fn status(&self, speed_m_s: f64) -> Result<Vec<SpanStatus>, RodError> {
        self.check_speed(speed_m_s)?;
        let mut spans = Vec::with_capacity(self.spans.len());
        for span in &self.spans {
            let mut stable = true;
            let mut worst: Option<f64> = None;
            let mut nearest: Option<f64> = None;
            let mut leave: Option<f64> = None;
            for source in &span.sources {
                let point = self.operating(span, source, speed_m_s);
                let exponent = self.exponent(&point, || self.describe(span, source))?;
                let point_stable = match exponent {
                    Some(e) => e <= 0.0,
                    None => point.a >= 0.0,
                };
                if let Some(e) = exponent {
                    let per_s = 0.5 * point.theta_rad_s * e;
                    worst = Some(worst.map_or(per_s, |w| w.max(per_s)));
                }
                let change =
                    speed_change(&source.bands, self.speed_range_m_s, speed_m_s).map(f64::abs);
                if point_stable {
                    if let Some(change) = change {
                        nearest = Some(nearest.map_or(change, |n| n.min(change)));
                    }
                } else {
                    stable = false;
                    leave = match (leave, change) {
                        // A point that no speed stabilises keeps the span unstable.
                        (_, None) => Some(f64::INFINITY),
                        (None, Some(change)) => Some(change),
                        (Some(l), Some(change)) => Some(l.max(change)),
                    };
                }
            }
            let speed_margin_m_s = if stable {
                nearest
            } else {
                leave.filter(|l| l.is_finite()).map(|l| -l)
            };
            spans.push(SpanStatus {
                span: self.mill.spans[span.span].name.clone(),
                stable,
                worst_exponent_per_s: worst,
                speed_margin_m_s,
            });
        }
        Ok(spans)
    }

    fn check_speed(&self, speed_m_s: f64) -> Result<(), RodError> {
        if speed_m_s.is_finite() && speed_m_s > 0.0 {
            Ok(())
        } else {
            Err(RodError::Pass {
                origin: self.pass.origin.clone(),
                key: "finishing_speed_m_s".to_owned(),
                value: format!("{speed_m_s}"),
                allowed: "> 0 m/s".to_owned(),
            })
        }
    }

    /// Every operating point at finishing speed `speed_m_s` (> 0; outside the
    /// configuration's range it is evaluated all the same).
    pub fn evaluate(&self, speed_m_s: f64) -> Result<PassReport, RodError> {
        self.check_speed(speed_m_s)?;
        let mut spans = Vec::with_capacity(self.spans.len());
        let mut worst: Option<f64> = None;
        for span in &self.spans {
            let mut points = Vec::with_capacity(span.sources.len());
            for source in &span.sources {
                let point = self.operating(span, source, speed_m_s);
                let exponent = self.exponent(&point, || self.describe(span, source))?;
                let location = match exponent {
                    Some(_) => Some(
                        self.mill
                            .mathieu
                            .locate(point.a, point.q, point.c)
                            .map_err(|error| RodError::Mathieu {
                                origin: self.pass.origin.clone(),
                                what: self.describe(span, source),
                                source: error,
                            })?,
                    ),
                    None => None,
                };
                let exponent_per_s = exponent.map(|e| 0.5 * point.theta_rad_s * e);
                let stable = match exponent {
                    Some(e) => e <= 0.0,
                    None => point.a >= 0.0,
                };
                if let Some(e) = exponent_per_s {
                    worst = Some(worst.map_or(e, |w| w.max(e)));
                }
                points.push(PointReport {
                    mode: source.mode,
                    source: source.label.clone(),
                    excitation: source.source,
                    f_rod_hz: point.f_rod_hz,
                    theta_hz: point.theta_rad_s / (2.0 * PI),
                    a: point.a,
                    q: point.q,
                    c: point.c,
                    tongue: location.map(|l| l.order),
                    inside: location.map(|l| l.inside),
                    exponent_per_s,
                    stable,
                    margin_a: location.map(|l| l.distance),
                    speed_change_m_s: speed_change(&source.bands, self.speed_range_m_s, speed_m_s),
                });
            }
            let mill_span = &self.mill.spans[span.span];
            let rod_speed = span.speed_share * speed_m_s;
            spans.push(SpanReport {
                span: mill_span.name.clone(),
                diameter_mm: span.beam.diameter_m * 1e3,
                rod_speed_m_s: rod_speed,
                v_over_v_crit: rod_speed / span.beam.critical_speed_m_s(),
                euler_load_n: span.beam.euler_load_n(),
                stable: points.iter().all(|p| p.stable),
                points,
            });
        }
        Ok(PassReport {
            pass: self.pass.name.clone(),
            configuration: self.mill.configurations[self.configuration].name.clone(),
            finishing_speed_m_s: speed_m_s,
            speed_range_m_s: self.speed_range_m_s,
            temperature_c: self.pass.temperature_c,
            modulus_pa: self.modulus_pa,
            stable: spans.iter().all(|s| s.stable),
            spans,
            worst_exponent_per_s: worst,
            avoid: self.avoid.clone(),
            unstable_at_every_speed: self.unstable_at_every_speed.clone(),
        })
    }
}

/// One span's stability at one finishing speed, without the tongue search: what a
/// service re-evaluates whenever the PLC's speed changes ([`PassSetup::status`]).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SpanStatus {
    /// `upstream - downstream`.
    pub span: String,
    /// No point of the span is unstable.
    pub stable: bool,
    /// Largest growth exponent of the span's points, 1/s (`None`: every point beyond
    /// the resolved range).
    pub worst_exponent_per_s: Option<f64>,
    /// Smallest finishing-speed change (m/s) that changes the stability of one of the
    /// span's points: positive when the span is stable (the distance to the nearest
    /// band), negative when it is not (minus the change that makes the last unstable
    /// point stable); `None` when no point has a band edge in the speed range (then
    /// `stable` cannot change with speed).
    pub speed_margin_m_s: Option<f64>,
}

/// Speed change from `speed` to the nearest band edge (to leave a band when inside
/// one), m/s; `None` without an edge inside the speed range (the range's own ends are
/// not edges: stability does not change there).
fn speed_change(bands: &[(f64, f64)], (lo, hi): (f64, f64), speed: f64) -> Option<f64> {
    bands
        .iter()
        .flat_map(|&(from, to)| [from, to])
        .filter(|&edge| edge > lo && edge < hi)
        .map(|edge| edge - speed)
        .min_by(|x, y| x.abs().total_cmp(&y.abs()))
}
