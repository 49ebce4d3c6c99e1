//! The excitation sources of each span: the torsional modes of the drive that swing
//! its two stands apart, and both stands' roll eccentricity, per rod bending mode.

use serde::Serialize;

use crate::rod::beam::Beam;
use crate::rod::mill::{ConfigurationModes, RodMill, Span};

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
    pub(crate) label: String,
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
    pub(crate) span: usize,
    /// The rod in this span (section, modulus, tension, ends).
    pub beam: Beam,
    /// Rod speed in the span over the finishing speed.
    pub(crate) speed_share: f64,
    /// Every mode and source.
    pub sources: Vec<SourceSetup>,
}

impl SpanSetup {
    /// Span `index` of `mill` in a pass of `diameters_m` (one per stand) at
    /// `modulus_pa` in configuration `modes`, its rod moving at `speed_share` of the
    /// finishing speed; no bands yet.
    pub(super) fn new(
        mill: &RodMill,
        index: usize,
        diameters_m: &[f64],
        modulus_pa: f64,
        modes: &ConfigurationModes,
        speed_share: f64,
    ) -> SpanSetup {
        let span = &mill.spans[index];
        let beam = Beam {
            length_m: span.length_m,
            diameter_m: diameters_m[span.upstream],
            density_kg_m3: mill.rod.density_kg_m3,
            modulus_pa,
            tension_n: span.tension_n,
            ends: span.ends,
        };
        let reference = mill.rod.epsilon * (beam.euler_load_n() + span.tension_n);
        let mut sources = Vec::new();
        for mode in 1..=mill.rod.modes {
            torsion_sources(mill, span, modes, mode, reference, &mut sources);
            eccentricity_sources(mill, span, mode, reference, &mut sources);
        }
        SpanSetup {
            span: index,
            beam,
            speed_share,
            sources,
        }
    }
}

/// The torsional modes of `modes` that swing `span`'s stands apart enough, acting on
/// bending mode `mode` with pulsation `reference` (N) times their participation.
fn torsion_sources(
    mill: &RodMill,
    span: &Span,
    modes: &ConfigurationModes,
    mode: usize,
    reference: f64,
    sources: &mut Vec<SourceSetup>,
) {
    for (frequency, shape) in modes.frequencies_hz.iter().zip(&modes.stand_shapes) {
        let participation =
            (shape[span.upstream] - shape[span.downstream]).abs() / std::f64::consts::SQRT_2;
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
}

/// Both stands' roll eccentricity at 1x and 2x, acting on bending mode `mode` with
/// pulsation `reference` (N).
fn eccentricity_sources(
    mill: &RodMill,
    span: &Span,
    mode: usize,
    reference: f64,
    sources: &mut Vec<SourceSetup>,
) {
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
