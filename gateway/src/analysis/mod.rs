//! The analysis task: samples in, bite and chatter results out. Only synchronous
//! `dsp` code runs on the samples; this module routes each reader message to the
//! drivelines whose torque or trigger it is ([`driveline`]) and to the tandem mills
//! whose stand it is ([`chatter_monitor`]).

pub mod bite_window;
pub mod chatter_monitor;
pub mod driveline;
mod error;
pub mod wear;

use std::sync::Arc;

use millgate_config::Config;
use tokio::sync::{broadcast, mpsc};

use crate::field::acquired::Acquired;
use crate::outputs::publisher::Publisher;
use crate::supervision::{Liveness, ANALYSIS_TICK};
use driveline::{BiteReport, DrivelineAnalyzer};
pub use error::AnalysisError;

/// The analysis task: consumes samples until every reader has hung up.
#[derive(Debug)]
pub struct Analysis {
    drivelines: Vec<DrivelineAnalyzer>,
    /// Per channel: the drivelines whose torque it is.
    by_torque: Vec<Vec<usize>>,
    /// Per channel: the drivelines it triggers.
    by_trigger: Vec<Vec<usize>>,
    publisher: Arc<Publisher>,
    bites: broadcast::Sender<BiteReport>,
    /// Chatter monitors of the tandem mills.
    chatter: chatter_monitor::ChatterAnalysis,
}

impl Analysis {
    /// Analysers for every driveline and chatter monitors for every tandem mill of
    /// `config`.
    pub fn new(
        config: &Config,
        publisher: Arc<Publisher>,
        bites: broadcast::Sender<BiteReport>,
    ) -> Result<Self, AnalysisError> {
        let mut by_torque = vec![Vec::new(); config.channels.len()];
        let mut by_trigger = vec![Vec::new(); config.channels.len()];
        let mut drivelines = Vec::new();
        for (index, driveline) in config.drivelines.iter().enumerate() {
            let torque = &config.channels[driveline.torque];
            drivelines.push(DrivelineAnalyzer::new(index, driveline, torque)?);
            by_torque[driveline.torque].push(index);
            if let Some(trigger) = driveline.metal_in_stand {
                by_trigger[trigger].push(index);
            }
        }
        let chatter = chatter_monitor::ChatterAnalysis::new(config, Arc::clone(&publisher))?;
        Ok(Self {
            drivelines,
            by_torque,
            by_trigger,
            publisher,
            bites,
            chatter,
        })
    }

    /// Handle one message from a reader; returns the bites it completed.
    pub fn handle(&mut self, message: Acquired) -> Vec<BiteReport> {
        self.chatter.handle(&message);
        let mut reports = Vec::new();
        match message {
            Acquired::Samples {
                channel,
                values,
                received,
            } => {
                for &d in &self.by_torque[channel] {
                    self.drivelines[d].samples(&values, received, &mut reports);
                }
            }
            Acquired::Gap {
                channel,
                missed_samples,
            } => {
                for &d in &self.by_torque[channel] {
                    self.drivelines[d].gap(missed_samples, &mut reports);
                }
            }
            Acquired::ProcessValue { channel, value } => {
                for &d in &self.by_trigger[channel] {
                    self.drivelines[d].trigger_value(value);
                }
            }
        }
        for report in &reports {
            self.drivelines[report.driveline].publish(&self.publisher, report);
            tracing::info!(
                driveline = %report.driveline_name,
                static_knm = report.transient.static_torque_knm,
                peak_knm = report.transient.peak_torque_knm,
                taf = ?report.transient.taf,
                beta_hz = ?report.beta_hz,
                degraded = report.degraded,
                wear_index = ?report.wear.map(|wear| wear.index),
                shift_over_linear_s = ?report.wear.and_then(|wear| wear.shift_excess_s),
                "bite"
            );
            // Nobody listening is fine: the demo and tests subscribe, the service need not.
            let _ = self.bites.send(report.clone());
        }
        reports
    }

    /// Run until every sender of `samples` is dropped, counting each turn of the loop
    /// (a message handled, or [`ANALYSIS_TICK`] without one) in `liveness`: a watchdog
    /// sees a stuck analysis as turns that stop.
    pub async fn run(mut self, mut samples: mpsc::Receiver<Acquired>, liveness: Arc<Liveness>) {
        let mut idle = tokio::time::interval(ANALYSIS_TICK);
        idle.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            tokio::select! {
                message = samples.recv() => match message {
                    Some(message) => {
                        self.handle(message);
                    }
                    None => break,
                },
                _ = idle.tick() => {}
            }
            liveness.analysis_turned();
        }
    }
}
