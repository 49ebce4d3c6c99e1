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

mod bands;
mod evaluate;
mod setup;
mod sources;
mod validate;

use std::sync::Arc;

use serde::Serialize;

pub use evaluate::{PassReport, PointReport, SpanReport, SpanStatus};
pub use setup::{AvoidBand, PassSetup};
pub use sources::{Source, SourceSetup, SpanSetup};

use super::mill::RodMill;
use super::schedule::Pass;
use super::RodError;

impl PassSetup {
    /// Validates `pass` against `mill` and computes the speed-independent part,
    /// including every source's unstable speed bands.
    pub fn new(mill: &Arc<RodMill>, pass: &Pass) -> Result<PassSetup, RodError> {
        let checked = validate::check_pass(mill, pass)?;
        let spans = (0..mill.spans.len())
            .map(|index| {
                let share = checked.stand_shares[mill.spans[index].upstream];
                SpanSetup::new(
                    mill,
                    index,
                    &pass.diameters_m,
                    checked.modulus_pa,
                    checked.modes,
                    share,
                )
            })
            .collect();
        let mut setup = PassSetup {
            mill: Arc::clone(mill),
            pass: pass.clone(),
            configuration: checked.configuration,
            speed_range_m_s: checked.modes.speed_range_m_s,
            finishing_speed_m_s: checked.finishing_speed_m_s,
            modulus_pa: checked.modulus_pa,
            stand_shares: checked.stand_shares,
            spans,
            avoid: Vec::new(),
            unstable_at_every_speed: Vec::new(),
        };
        setup.find_bands()?;
        setup.avoid = setup.merged_bands();
        setup.unstable_at_every_speed = setup.unstable_everywhere();
        Ok(setup)
    }
}

/// A whole schedule checked at each pass's finishing speed.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ScheduleReport {
    /// The mill's name.
    pub(crate) mill: String,
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
    pub(crate) name: String,
    /// Finishing-speed range of the gearbox in it, m/s.
    pub(crate) speed_range_m_s: (f64, f64),
    /// Torsional natural frequencies of the drive in it, Hz.
    pub(crate) torsional_hz: Vec<f64>,
    /// For each pass rolled in it, the finishing speeds to avoid.
    pub passes: Vec<PassBands>,
}

/// The finishing speeds one pass must avoid.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PassBands {
    /// Pass name.
    pub pass: String,
    /// Bands, m/s, ascending.
    pub(crate) avoid: Vec<AvoidBand>,
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
