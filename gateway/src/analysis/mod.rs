//! The analysis task: samples in, bite and chatter results out. Only synchronous
//! `dsp` code runs on the samples; this module routes each reader message to the
//! drivelines whose torque or trigger it is ([`driveline`]) and to the tandem mills
//! whose stand it is ([`chatter_monitor`]).

pub mod bite_window;
pub mod chatter_monitor;
pub mod driveline;
pub mod wear;

use std::sync::Arc;

use millgate_config::Config;
use millgate_dsp::bite::BiteSettingsError;
use tokio::sync::{broadcast, mpsc};

use crate::field::acquired::Acquired;
use crate::outputs::publisher::Publisher;
use bite_window::{PRE_TRIGGER_CAPACITY, WINDOW_CAPACITY};
use driveline::{BiteReport, DrivelineAnalyzer};

/// A driveline or tandem mill of the configuration that the analysis cannot be built
/// for. Each message starts with the key at fault (`drivelines[0].bite`), as the
/// configuration's own problems do.
#[derive(Debug, thiserror::Error)]
pub enum AnalysisError {
    /// A tandem mill the chatter monitor cannot be built for.
    #[error(transparent)]
    Chatter(#[from] chatter_monitor::ChatterSetupError),
    /// The bite window needs more samples than the detector holds.
    #[error(
        "drivelines[{index}].bite: pre_trigger_s {pre_trigger_s} s and post_trigger_s \
         {post_trigger_s} s at {sample_rate_hz} Hz need {pre_samples} + {post_samples} \
         samples; the bite detector holds at most {PRE_TRIGGER_CAPACITY} + {} samples",
        WINDOW_CAPACITY - PRE_TRIGGER_CAPACITY
    )]
    BiteWindow {
        /// Index of the driveline in the configuration.
        index: usize,
        /// Configured capture before the trigger, s.
        pre_trigger_s: f64,
        /// Configured capture after the trigger, s.
        post_trigger_s: f64,
        /// Sample rate of the torque channel, Hz.
        sample_rate_hz: f64,
        /// Samples before the trigger that asks for.
        pre_samples: usize,
        /// Samples from the trigger on that asks for.
        post_samples: usize,
    },
    /// The bite detector refused the settings derived from the driveline.
    #[error("drivelines[{index}].bite: {source}")]
    BiteSettings {
        /// Index of the driveline in the configuration.
        index: usize,
        /// What the detector refused.
        #[source]
        source: BiteSettingsError,
    },
    /// The driveline's model file (for the wear index) is not a valid model.
    #[error("drivelines[{index}].model: {source}")]
    Model {
        /// Index of the driveline in the configuration.
        index: usize,
        /// What is wrong with the model file (it names the file and the key).
        #[source]
        source: millgate_sim::model::ModelError,
    },
}

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

    /// Run until every sender of `samples` is dropped.
    pub async fn run(mut self, mut samples: mpsc::Receiver<Acquired>) {
        while let Some(message) = samples.recv().await {
            self.handle(message);
        }
    }
}
