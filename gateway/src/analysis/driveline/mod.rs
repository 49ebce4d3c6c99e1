//! One driveline's bites: detection on its torque channel (and its "metal in stand"
//! trigger), the window analysis, the wear index against its model, and the results
//! published for the register map.
//!
//! One file per job, along the data path:
//!
//! - `setup`: how the bites are detected and analysed ([`BiteSetup`]), and what the
//!   driveline's model gives the wear diagnosis;
//! - `capture`: what the history's captures keep of the samples ([`BiteSamples`], the
//!   extra channels' rings, the manual captures);
//! - `analyzer`: the driveline's analyser, built from the configuration, holding the
//!   detector, the wear diagnosis and the captures between bites;
//! - `report`: samples in, each completed window analysed into a [`BiteReport`];
//! - `publish`: each report into the published results and the history, under the
//!   board's lock ([`bite_record`]).

mod analyzer;
mod capture;
mod publish;
mod report;
mod setup;

pub use super::context::BiteContext;
pub(super) use analyzer::DrivelineAnalyzer;
pub use capture::BiteSamples;
pub use publish::bite_record;
pub(super) use publish::publish_bites;
pub use report::BiteReport;
pub use setup::BiteSetup;
