//! What the outputs publish: the latest [`Results`] joined with source health,
//! encoded through the [`RegisterMap`].

use std::sync::atomic::{AtomicU16, Ordering};
use std::sync::{Arc, Mutex};

use millgate_config::{ChannelSource, Config};

use crate::analysis::gap_map::GapMaps;
use crate::field::source_health::{SourceHealth, SourceStatus};
use crate::outputs::history::events::{
    AlarmEvent, AlarmKind, AlarmRecord, CommandOrigin, HistoryEvent,
};
use crate::outputs::history::time::UtcTime;
use crate::outputs::history::History;
use crate::outputs::register_map::RegisterMap;
use crate::outputs::results::Results;

/// Shared between the analysis task (writes results) and the outputs (read them).
#[derive(Debug)]
pub struct Publisher {
    results: Mutex<Results>,
    /// Wakes the PLC writer when results change, so a bite is written at once
    /// rather than at the next write period.
    changed: tokio::sync::Notify,
    map: RegisterMap,
    health: Vec<Arc<SourceHealth>>,
    /// The source statuses of the final image, once the service stops.
    frozen_health: Mutex<Option<Vec<SourceStatus>>>,
    driveline_names: Vec<String>,
    mill_names: Vec<String>,
    /// Global source index of each driveline's torque channel.
    driveline_sources: Vec<usize>,
    /// Global source indices of each mill's stand channels.
    mill_sources: Vec<Vec<usize>>,
    /// Where changes are recorded (disabled without `[history]`).
    history: History,
    /// Global source indices of each rod mill's input channels.
    rod_mill_sources: Vec<Vec<usize>>,
    /// Drivelines (bit k = driveline k) whose wear was reset since the analysis last
    /// looked: it empties their gap pools.
    wear_resets: AtomicU16,
    /// Each driveline's gap maps, for the maintenance page's wear map curves.
    wear_maps: Mutex<Vec<WearMapState>>,
}

/// Where a driveline's gap maps are (the analysis holds its own reference; this one
/// is for the outputs that draw them).
#[derive(Debug, Clone)]
pub enum WearMapState {
    /// The driveline has no model: no maps.
    NoModel,
    /// Read from the cache or being built: `done` of `total` simulations.
    Building {
        /// Simulations done.
        done: usize,
        /// Simulations the build runs (0 until the build reports).
        total: usize,
    },
    /// Ready.
    Ready(Arc<GapMaps>),
    /// Will not come: why (the model does not load or fit, the build failed).
    Failed(String),
}

/// Global index of a channel's source: Modbus sources first, then CAN sources.
pub fn source_of_channel(config: &Config, channel: usize) -> usize {
    match config.channels[channel].source {
        ChannelSource::ModbusBlock { source, .. } | ChannelSource::ModbusValue { source, .. } => {
            source
        }
        ChannelSource::Can { source, .. } => config.modbus_sources.len() + source,
    }
}

impl Publisher {
    /// A publisher for `config` with one health record per source (Modbus, then CAN).
    pub fn new(config: &Config, health: Vec<Arc<SourceHealth>>) -> Self {
        let mut results = Results::new(
            health.len(),
            config.drivelines.len(),
            config.tandem_mills.len(),
        );
        results.rod_mills = vec![Default::default(); config.rod_mills.len()];
        Self {
            results: Mutex::new(results),
            changed: tokio::sync::Notify::new(),
            map: RegisterMap::new(config),
            health,
            frozen_health: Mutex::new(None),
            driveline_names: config.drivelines.iter().map(|d| d.name.clone()).collect(),
            mill_names: config.tandem_mills.iter().map(|m| m.name.clone()).collect(),
            driveline_sources: config
                .drivelines
                .iter()
                .map(|d| source_of_channel(config, d.torque))
                .collect(),
            mill_sources: config
                .tandem_mills
                .iter()
                .map(|m| {
                    m.stands
                        .iter()
                        .map(|&c| source_of_channel(config, c))
                        .collect()
                })
                .collect(),
            history: History::disabled(),
            rod_mill_sources: config
                .rod_mills
                .iter()
                .map(|m| {
                    [Some(m.configuration), Some(m.pass), Some(m.finishing_speed)]
                        .into_iter()
                        .chain([m.temperature])
                        .flatten()
                        .map(|c| source_of_channel(config, c))
                        .collect()
                })
                .collect(),
            wear_resets: AtomicU16::new(0),
            wear_maps: Mutex::new(
                config
                    .drivelines
                    .iter()
                    .map(|d| match d.model {
                        Some(_) => WearMapState::Building { done: 0, total: 0 },
                        None => WearMapState::NoModel,
                    })
                    .collect(),
            ),
        }
    }

    /// Driveline `index`'s gap maps.
    pub fn wear_map(&self, index: usize) -> Option<WearMapState> {
        crate::lock(&self.wear_maps).get(index).cloned()
    }

    /// Set driveline `index`'s gap maps (a progress report of a build that has
    /// finished or failed is ignored).
    pub fn set_wear_map(&self, index: usize, state: WearMapState) {
        let mut maps = crate::lock(&self.wear_maps);
        if let Some(slot) = maps.get_mut(index) {
            let late = matches!(state, WearMapState::Building { .. })
                && !matches!(slot, WearMapState::Building { .. });
            if !late {
                *slot = state;
            }
        }
    }

    /// This publisher recording into `history`.
    pub fn with_history(mut self, history: History) -> Self {
        self.history = history;
        self
    }

    /// The history changes are recorded into.
    pub fn history(&self) -> &History {
        &self.history
    }

    /// The register map.
    pub fn map(&self) -> &RegisterMap {
        &self.map
    }

    /// Driveline names, in config order.
    pub fn driveline_names(&self) -> &[String] {
        &self.driveline_names
    }

    /// Tandem mill names, in config order.
    pub fn mill_names(&self) -> &[String] {
        &self.mill_names
    }

    /// Change the results.
    pub fn update<T>(&self, change: impl FnOnce(&mut Results) -> T) -> T {
        self.update_recorded(|results, _| change(results))
    }

    /// Change the results and record what happened (the events `change` pushes) in
    /// the history, under one lock: whoever reads the results after this call finds
    /// the events already counted in [`History::enqueued`], which is what lets the
    /// PLC writer wait until a bite it writes is stored.
    pub fn update_recorded<T>(
        &self,
        change: impl FnOnce(&mut Results, &mut Vec<HistoryEvent>) -> T,
    ) -> T {
        let mut results = crate::lock(&self.results);
        let mut events = Vec::new();
        let value = change(&mut results, &mut events);
        for event in events {
            self.history.record(event);
        }
        drop(results);
        self.changed.notify_one();
        value
    }

    /// Wait until the results change (returns at once if they changed since the
    /// last wait).
    pub async fn changed(&self) {
        self.changed.notified().await;
    }

    /// A copy of the results with current source health applied.
    pub fn results(&self) -> Results {
        let mut results = crate::lock(&self.results).clone();
        self.apply_health(&mut results);
        results
    }

    /// Keep the source statuses as they are now in every later image: the readers are
    /// about to stop, and a source they stop reading is not a source gone stale. The
    /// final image of an orderly stop shows the sources as they were while running.
    pub fn freeze_health(&self) {
        let statuses = self.health.iter().map(|h| h.status()).collect();
        *crate::lock(&self.frozen_health) = Some(statuses);
    }

    fn apply_health(&self, results: &mut Results) {
        let frozen = crate::lock(&self.frozen_health).clone();
        let statuses: Vec<SourceStatus> =
            frozen.unwrap_or_else(|| self.health.iter().map(|h| h.status()).collect());
        results.sources = statuses.iter().copied().map(Some).collect();
        let bad = |source: &usize| {
            statuses
                .get(*source)
                .is_some_and(|s| *s != SourceStatus::Ok)
        };
        for (driveline, source) in results.drivelines.iter_mut().zip(&self.driveline_sources) {
            driveline.source_stale = bad(source);
        }
        // A mill is also flagged by its analysis (a gap restarted its window).
        for (mill, sources) in results.mills.iter_mut().zip(&self.mill_sources) {
            mill.source_stale |= sources.iter().any(bad);
        }
        for (mill, sources) in results.rod_mills.iter_mut().zip(&self.rod_mill_sources) {
            mill.source_stale = sources.iter().any(bad);
        }
    }

    /// Increment the heartbeat counter (each PLC write period, or each second
    /// without a PLC output), so a watchdog sees the gateway alive.
    /// Not a change of the results: waiters on [`Self::changed`] are not woken (the
    /// PLC writer beats on each write and would wake itself).
    pub fn beat(&self) {
        let mut results = crate::lock(&self.results);
        results.heartbeat = results.heartbeat.wrapping_add(1);
    }

    /// Encode the map as published now.
    pub fn words(&self) -> Vec<u16> {
        self.map.encode(&self.results())
    }

    /// Forget the wear trend and the gap estimate of every driveline whose bit is set
    /// in `drivelines` (bit k = driveline k in config order): the next bite's wear
    /// index seeds the trend afresh and the gap pool starts empty (the reset-wear-trend
    /// command, e.g. after a coupling is replaced). The gap alarm stays latched until
    /// acknowledged. `origin` says who, for the history.
    pub fn reset_wear_trend(&self, drivelines: u16, origin: CommandOrigin) {
        let time = UtcTime::now();
        self.wear_resets.fetch_or(drivelines, Ordering::Relaxed);
        self.update_recorded(|results, events| {
            for (k, driveline) in results.drivelines.iter_mut().enumerate().take(16) {
                if drivelines & (1 << k) != 0 {
                    driveline.wear_trend = None;
                    driveline.gap = None;
                    driveline.gap_warning = false;
                    events.push(HistoryEvent::WearReset {
                        time,
                        driveline: self.driveline_names[k].clone(),
                        origin,
                    });
                }
            }
        });
    }

    /// The drivelines reset since the last call (bit k = driveline k): the analysis
    /// empties their gap pools.
    pub fn take_wear_resets(&self) -> u16 {
        self.wear_resets.swap(0, Ordering::Relaxed)
    }

    /// Clear latched alarms (the acknowledge command); `origin` says who, for the
    /// history, which records each alarm that was latched.
    pub fn acknowledge_alarms(&self, origin: CommandOrigin) {
        let time = UtcTime::now();
        let acknowledged = |subject: &String, kind| {
            HistoryEvent::Alarm(AlarmRecord {
                time,
                subject: subject.clone(),
                kind,
                event: AlarmEvent::Acknowledged,
                origin: Some(origin),
                value: None,
                threshold: None,
            })
        };
        self.update_recorded(|results, events| {
            for (driveline, name) in results.drivelines.iter_mut().zip(&self.driveline_names) {
                if driveline.alarm {
                    events.push(acknowledged(name, AlarmKind::TafAlarm));
                }
                if driveline.gap_alarm {
                    events.push(acknowledged(name, AlarmKind::WearAlarm));
                }
                driveline.alarm = false;
                driveline.gap_alarm = false;
            }
            for (mill, name) in results.mills.iter_mut().zip(&self.mill_names) {
                if mill.alarm {
                    events.push(acknowledged(name, AlarmKind::ChatterAlarm));
                }
                mill.alarm = false;
            }
        });
    }
}
