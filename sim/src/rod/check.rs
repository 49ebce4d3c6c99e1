//! One pass: the stability of every span, bending mode and excitation source, and the
//! finishing speeds to avoid.
//!
//! [`PassSetup::new`] validates the pass against the mill and computes everything that
//! does not depend on the finishing speed: each span's beam (section, modulus,
//! tension), each source's pulsation amplitude, and each source's unstable
//! finishing-speed bands over the configuration's speed range. [`PassSetup::evaluate`]
//! then gives the operating points at one finishing speed, cheaply: for each point
//! `a`, `q`, `c`, the growth exponent, the nearest (damped) tongue and the signed
//! distance to its edge in `a` (at fixed `q` and `c`), and the finishing-speed change to
//! the nearest band edge.
//!
//! How the quantities move with the finishing speed `V` (stand exit speeds are fixed
//! shares of it, by mass flow or as given): an eccentricity source's `Theta` is
//! `2 h V_i / D_i` (rad/s, harmonic h of stand i's roll speed `V_i / (pi D_i)`), so `a`
//! and `q` fall as `1/V^2`; a torsional source's `Theta` is fixed, so only the moving-rod
//! term (when enabled) moves its point. Bands are found on a grid of 200 speeds plus the
//! speeds at which `a - c^2` passes each tongue's centre `n^2` (so a tongue narrower than
//! the grid step is not stepped over), then every change of stability is bisected to
//! 1e-9 of the range.

use std::f64::consts::PI;
use std::sync::Arc;

use millgate_dsp::mathieu::{MAX_ABS_A, MAX_ABS_Q, MAX_DAMPING, MAX_ORDER};
use serde::Serialize;

use super::beam::Beam;
use super::mill::RodMill;
use super::schedule::Pass;
use super::RodError;

/// Grid speeds per configuration range in the band search (plus the tongue centres).
const GRID: usize = 200;

/// Bisection steps refining a band edge (2^-40 of the range).
const EDGE_STEPS: usize = 40;

/// Where the pulsation of a span's tension comes from.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Source {
    /// A torsional mode of the drive in the pass's configuration.
    Torsion {
        /// Natural frequency, Hz.
        frequency_hz: f64,
        /// `|phi_up - phi_down| / sqrt(2)` of the unit-norm shape, 0..=1.
        participation: f64,
    },
    /// Roll eccentricity of a stand at a harmonic of its roll speed.
    Eccentricity {
        /// Index of the stand (rolling order).
        stand: usize,
        /// 1 or 2 (times the roll speed).
        harmonic: u8,
    },
}

/// One excitation source acting on one bending mode of a span.
#[derive(Debug, Clone, PartialEq)]
pub struct SourceSetup {
    /// Rod bending mode, 1-based.
    pub mode: usize,
    /// The source.
    pub source: Source,
    /// Label for reports (`torsion 31.8 Hz`, `stand 2 roll 1x`).
    pub label: String,
    /// Pulsation amplitude P, N.
    pub pulsation_n: f64,
    /// Finishing-speed intervals (m/s) within the configuration's range where this
    /// point is unstable, ascending.
    pub bands: Vec<(f64, f64)>,
}

/// One span in one pass.
#[derive(Debug, Clone, PartialEq)]
pub struct SpanSetup {
    /// Index of the span in the mill.
    pub span: usize,
    /// The rod in this span (section, modulus, tension, ends).
    pub beam: Beam,
    /// Rod speed in the span over the finishing speed.
    pub speed_share: f64,
    /// Every mode and source.
    pub sources: Vec<SourceSetup>,
}

/// A band of finishing speed to avoid, with the sources that make it unstable.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AvoidBand {
    /// Lower edge, m/s.
    pub from_m_s: f64,
    /// Upper edge, m/s.
    pub to_m_s: f64,
    /// `span / mode / source` of every unstable point in it.
    pub sources: Vec<String>,
}

/// One pass, validated, with everything that does not depend on the finishing speed.
///
/// It shares the mill (`Arc`), so a long-lived task can keep the mill and the active
/// pass's setup side by side and rebuild only the setup when the pass changes.
#[derive(Debug, Clone)]
pub struct PassSetup {
    mill: Arc<RodMill>,
    /// The pass as given.
    pub pass: Pass,
    /// Index of its configuration in [`RodMill::configurations`].
    pub configuration: usize,
    /// The configuration's finishing-speed range, m/s.
    pub speed_range_m_s: (f64, f64),
    /// The pass's finishing speed, m/s.
    pub finishing_speed_m_s: f64,
    /// Young's modulus at the pass's temperature, Pa.
    pub modulus_pa: f64,
    /// Rod exit speed of each stand over the finishing speed.
    pub stand_shares: Vec<f64>,
    /// Every span.
    pub spans: Vec<SpanSetup>,
    /// Union of the sources' bands that end or start inside the speed range (a change
    /// of speed helps), ascending.
    pub avoid: Vec<AvoidBand>,
    /// `span / mode / source` of every point unstable over the whole speed range (a
    /// torsional source without the moving-rod term: no speed helps).
    pub unstable_at_every_speed: Vec<String>,
}

/// The Mathieu point of one source at one speed.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Operating {
    a: f64,
    q: f64,
    c: f64,
    theta_rad_s: f64,
    f_rod_hz: f64,
}

/// One operating point at one finishing speed.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PointReport {
    /// Rod bending mode, 1-based.
    pub mode: usize,
    /// Source label.
    pub source: String,
    /// The source itself.
    pub excitation: Source,
    /// Rod natural frequency of this mode, Hz.
    pub f_rod_hz: f64,
    /// Pulsation frequency Theta, Hz.
    pub theta_hz: f64,
    /// Mathieu a = 4 omega^2 / Theta^2.
    pub a: f64,
    /// Mathieu q = 2 g P / (L^2 rho A Theta^2).
    pub q: f64,
    /// Damping c = zeta sqrt(a), per unit Mathieu time.
    pub c: f64,
    /// Order of the nearest damped tongue (`None` beyond the resolved range).
    pub tongue: Option<u8>,
    /// Inside it.
    pub inside: Option<bool>,
    /// Growth exponent, 1/s (negative: decays); `None` beyond the resolved range.
    pub exponent_per_s: Option<f64>,
    /// Stable (exponent <= 0).
    pub stable: bool,
    /// Signed distance in a to the nearest damped tongue edge (> 0 stable).
    pub margin_a: Option<f64>,
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
    pub diameter_mm: f64,
    /// Rod speed in the span, m/s.
    pub rod_speed_m_s: f64,
    /// Rod speed over the span's critical speed (reported whether or not the moving-rod
    /// term is on).
    pub v_over_v_crit: f64,
    /// Euler load of the span, N.
    pub euler_load_n: f64,
    /// Every mode and source.
    pub points: Vec<PointReport>,
    /// No point is unstable.
    pub stable: bool,
}

/// One pass at one finishing speed.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PassReport {
    /// Pass name.
    pub pass: String,
    /// Configuration name.
    pub configuration: String,
    /// Finishing speed evaluated, m/s.
    pub finishing_speed_m_s: f64,
    /// The configuration's finishing-speed range, m/s.
    pub speed_range_m_s: (f64, f64),
    /// Rod temperature, deg C.
    pub temperature_c: f64,
    /// Young's modulus at it, Pa.
    pub modulus_pa: f64,
    /// Every span.
    pub spans: Vec<SpanReport>,
    /// No point of any span is unstable.
    pub stable: bool,
    /// Largest growth exponent of any point, 1/s.
    pub worst_exponent_per_s: Option<f64>,
    /// Finishing speeds to avoid in this pass's geometry, m/s.
    pub avoid: Vec<AvoidBand>,
    /// Points unstable at every speed of the range (no speed change helps).
    pub unstable_at_every_speed: Vec<String>,
}

impl PassSetup {
    /// Validates `pass` against `mill` and computes the speed-independent part,
    /// including every source's unstable speed bands.
    pub fn new(mill: &Arc<RodMill>, pass: &Pass) -> Result<PassSetup, RodError> {
        let refuse = |key: &str, value: String, allowed: String| RodError::Pass {
            origin: pass.origin.clone(),
            key: key.to_owned(),
            value,
            allowed,
        };
        let Some((configuration, modes)) = mill.configuration(&pass.configuration) else {
            let known: Vec<String> = mill
                .configurations
                .iter()
                .map(|c| format!("{:?}", c.name))
                .collect();
            return Err(refuse(
                "configuration",
                format!("{:?}", pass.configuration),
                format!("a configuration of the drive (known: {})", known.join(", ")),
            ));
        };
        let stands = mill.stands.len();
        if pass.diameters_m.len() != stands {
            return Err(refuse(
                "diameters_mm",
                format!("{} values", pass.diameters_m.len()),
                format!("one per stand: {stands} values"),
            ));
        }
        if let Some(bad) = pass
            .diameters_m
            .iter()
            .find(|d| !(d.is_finite() && **d > 0.0))
        {
            return Err(refuse(
                "diameters_mm",
                format!("{}", bad * 1e3),
                "> 0 mm".to_owned(),
            ));
        }
        let (t_lo, t_hi) = mill.temperature_range_c();
        let modulus_pa = mill.modulus_pa(pass.temperature_c).ok_or_else(|| {
            refuse(
                "temperature_c",
                format!("{}", pass.temperature_c),
                format!("within the modulus table, {t_lo} ..= {t_hi} deg C"),
            )
        })?;
        let (finishing_speed_m_s, stand_shares) =
            match (&pass.stand_speeds_m_s, pass.finishing_speed_m_s) {
                (Some(speeds), _) => {
                    if speeds.len() != stands {
                        return Err(refuse(
                            "stand_speeds_m_s",
                            format!("{} values", speeds.len()),
                            format!("one per stand: {stands} values"),
                        ));
                    }
                    if let Some(bad) = speeds.iter().find(|v| !(v.is_finite() && **v > 0.0)) {
                        return Err(refuse(
                            "stand_speeds_m_s",
                            format!("{bad}"),
                            "> 0 m/s".to_owned(),
                        ));
                    }
                    let last = speeds[stands - 1];
                    (last, speeds.iter().map(|v| v / last).collect::<Vec<f64>>())
                }
                (None, Some(speed)) => {
                    let finishing = pass.diameters_m[stands - 1];
                    let shares = pass
                        .diameters_m
                        .iter()
                        .map(|d| (finishing / d).powi(2))
                        .collect();
                    (speed, shares)
                }
                (None, None) => {
                    return Err(refuse(
                        "finishing_speed_m_s",
                        "missing".to_owned(),
                        "> 0 m/s".to_owned(),
                    ));
                }
            };
        let (v_lo, v_hi) = modes.speed_range_m_s;
        if !(finishing_speed_m_s.is_finite() && finishing_speed_m_s > 0.0) {
            return Err(refuse(
                "finishing_speed_m_s",
                format!("{finishing_speed_m_s}"),
                format!(
                    "> 0 m/s, within configuration {:?}'s range {v_lo:.1} ..= {v_hi:.1} m/s",
                    modes.name
                ),
            ));
        }
        // A relative slack of 1e-9 absorbs rounding at the range's ends.
        if finishing_speed_m_s < v_lo * (1.0 - 1e-9) || finishing_speed_m_s > v_hi * (1.0 + 1e-9) {
            return Err(refuse(
                "finishing_speed_m_s",
                format!("{finishing_speed_m_s}"),
                format!(
                    "within configuration {:?}'s range {v_lo:.1} ..= {v_hi:.1} m/s (motor {} ..= {} rpm)",
                    modes.name, mill.motor_rpm.0, mill.motor_rpm.1
                ),
            ));
        }
        let mut setup = PassSetup {
            mill: Arc::clone(mill),
            pass: pass.clone(),
            configuration,
            speed_range_m_s: modes.speed_range_m_s,
            finishing_speed_m_s,
            modulus_pa,
            stand_shares,
            spans: Vec::new(),
            avoid: Vec::new(),
            unstable_at_every_speed: Vec::new(),
        };
        for (index, span) in mill.spans.iter().enumerate() {
            let beam = Beam {
                length_m: span.length_m,
                diameter_m: pass.diameters_m[span.upstream],
                density_kg_m3: mill.rod.density_kg_m3,
                modulus_pa,
                tension_n: span.tension_n,
                ends: span.ends,
            };
            let reference = mill.rod.epsilon * (beam.euler_load_n() + span.tension_n);
            let mut sources = Vec::new();
            for mode in 1..=mill.rod.modes {
                for (frequency, shape) in modes.frequencies_hz.iter().zip(&modes.stand_shapes) {
                    let participation = (shape[span.upstream] - shape[span.downstream]).abs()
                        / std::f64::consts::SQRT_2;
                    if participation >= mill.rod.min_participation && participation > 0.0 {
                        sources.push(SourceSetup {
                            mode,
                            source: Source::Torsion {
                                frequency_hz: *frequency,
                                participation,
                            },
                            label: format!("torsion {frequency:.1} Hz ({participation:.2})"),
                            pulsation_n: reference * participation,
                            bands: Vec::new(),
                        });
                    }
                }
                for stand in [span.upstream, span.downstream] {
                    for harmonic in [1_u8, 2] {
                        sources.push(SourceSetup {
                            mode,
                            source: Source::Eccentricity { stand, harmonic },
                            label: format!("{} roll {harmonic}x", mill.stands[stand].name),
                            pulsation_n: reference,
                            bands: Vec::new(),
                        });
                    }
                }
            }
            setup.spans.push(SpanSetup {
                span: index,
                beam,
                speed_share: setup.stand_shares[span.upstream],
                sources,
            });
        }
        for s in 0..setup.spans.len() {
            for k in 0..setup.spans[s].sources.len() {
                let bands = setup.bands(&setup.spans[s], &setup.spans[s].sources[k])?;
                setup.spans[s].sources[k].bands = bands;
            }
        }
        setup.avoid = setup.merged_bands();
        setup.unstable_at_every_speed = setup
            .spans
            .iter()
            .flat_map(|span| span.sources.iter().map(move |source| (span, source)))
            .filter(|(_, source)| source.bands == [setup.speed_range_m_s])
            .map(|(span, source)| setup.describe(span, source))
            .collect();
        Ok(setup)
    }

    /// The mill this pass runs on.
    pub fn mill(&self) -> &RodMill {
        &self.mill
    }

    /// Mathieu point of `source` in `span` at finishing speed `speed`.
    fn operating(&self, span: &SpanSetup, source: &SourceSetup, speed: f64) -> Operating {
        let rod = &self.mill.rod;
        let axial = if rod.moving_rod {
            span.speed_share * speed
        } else {
            0.0
        };
        let omega_squared = span.beam.omega_squared(source.mode, axial);
        let theta_rad_s = match source.source {
            Source::Torsion { frequency_hz, .. } => 2.0 * PI * frequency_hz,
            Source::Eccentricity { stand, harmonic } => {
                2.0 * f64::from(harmonic) * self.stand_shares[stand] * speed
                    / self.mill.stands[stand].roll_diameter_m
            }
        };
        let theta_squared = theta_rad_s * theta_rad_s;
        let a = 4.0 * omega_squared / theta_squared;
        let q = span.beam.q_factor(source.mode) * source.pulsation_n / theta_squared;
        Operating {
            a,
            q,
            c: rod.damping_ratio * a.max(0.0).sqrt(),
            theta_rad_s,
            f_rod_hz: omega_squared.max(0.0).sqrt() / (2.0 * PI),
        }
    }

    /// Growth exponent per unit Mathieu time, `None` beyond the resolved range (there:
    /// a buckled rod, a < -1e4, counts as unstable, anything else as stable; see
    /// [`super::mill::MAX_EPSILON`]).
    fn exponent(
        &self,
        point: &Operating,
        what: impl FnOnce() -> String,
    ) -> Result<Option<f64>, RodError> {
        let resolved = point.a.abs() <= MAX_ABS_A
            && point.q.abs() <= MAX_ABS_Q
            && point.c <= MAX_DAMPING
            && (point.a - point.c * point.c).abs() <= MAX_ABS_A;
        if !resolved {
            return Ok(None);
        }
        self.mill
            .mathieu
            .exponent(point.a, point.q, point.c)
            .map(Some)
            .map_err(|source| RodError::Mathieu {
                origin: self.pass.origin.clone(),
                what: what(),
                source,
            })
    }

    fn unstable(
        &self,
        span: &SpanSetup,
        source: &SourceSetup,
        speed: f64,
    ) -> Result<bool, RodError> {
        let point = self.operating(span, source, speed);
        Ok(
            match self.exponent(&point, || self.describe(span, source))? {
                Some(exponent) => exponent > 0.0,
                None => point.a < 0.0,
            },
        )
    }

    fn describe(&self, span: &SpanSetup, source: &SourceSetup) -> String {
        format!(
            "{} / mode {} / {}",
            self.mill.spans[span.span].name, source.mode, source.label
        )
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
    fn merged_bands(&self) -> Vec<AvoidBand> {
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

/// A whole schedule checked at each pass's finishing speed.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ScheduleReport {
    /// The mill's name.
    pub mill: String,
    /// Every pass, in schedule order.
    pub passes: Vec<PassReport>,
    /// Per configuration: speed range, torsional modes, and the bands each of its
    /// passes must avoid.
    pub configurations: Vec<ConfigurationReport>,
}

/// One configuration of the drive in a schedule report.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ConfigurationReport {
    /// Configuration name.
    pub name: String,
    /// Finishing-speed range of the gearbox in it, m/s.
    pub speed_range_m_s: (f64, f64),
    /// Torsional natural frequencies of the drive in it, Hz.
    pub torsional_hz: Vec<f64>,
    /// For each pass rolled in it, the finishing speeds to avoid.
    pub passes: Vec<PassBands>,
}

/// The finishing speeds one pass must avoid.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PassBands {
    /// Pass name.
    pub pass: String,
    /// Bands, m/s, ascending.
    pub avoid: Vec<AvoidBand>,
    /// Points unstable at every speed of the range.
    pub unstable_at_every_speed: Vec<String>,
}

/// Every pass of a schedule at its own finishing speed, and the bands to avoid per
/// configuration.
pub fn check_schedule(mill: &Arc<RodMill>, passes: &[Pass]) -> Result<ScheduleReport, RodError> {
    let reports = passes
        .iter()
        .map(|pass| {
            let setup = PassSetup::new(mill, pass)?;
            setup.evaluate(setup.finishing_speed_m_s)
        })
        .collect::<Result<Vec<PassReport>, RodError>>()?;
    let configurations = mill
        .configurations
        .iter()
        .map(|configuration| ConfigurationReport {
            name: configuration.name.clone(),
            speed_range_m_s: configuration.speed_range_m_s,
            torsional_hz: configuration.frequencies_hz.clone(),
            passes: reports
                .iter()
                .filter(|r| r.configuration == configuration.name)
                .map(|r| PassBands {
                    pass: r.pass.clone(),
                    avoid: r.avoid.clone(),
                    unstable_at_every_speed: r.unstable_at_every_speed.clone(),
                })
                .collect(),
        })
        .collect();
    Ok(ScheduleReport {
        mill: mill.name.clone(),
        passes: reports,
        configurations,
    })
}
