//! Rod mills online: each span's parametric stability at the PLC's live operating
//! point (issue 17; domain notes 3, the library in [`millgate_sim::rod`]).
//!
//! A `[[rod_mills]]` entry names the rod-mill file, the pass schedule and four PLC
//! process values, read like every other process value by the Modbus reader
//! ([`crate::field::modbus`]): the active drive configuration (value k selects
//! `configurations[k]`), the pass number (1-based row of the schedule, which gives
//! the rod diameters and, without a temperature channel, the rod temperature), the
//! finishing speed (m/s) and optionally the rod temperature (deg C).
//!
//! - **Setups**: the speed-independent part of a pass ([`PassSetup::new`], ~4 ms:
//!   the configuration's torsional modes, the rod beams, every source's unstable
//!   speed bands) is computed when the pass, the configuration or the rounded
//!   temperature changes, and cached by that key (at most [`MAX_CACHED_SETUPS`]
//!   entries): switching back to a pass or configuration seen before costs nothing.
//!   The temperature is rounded to `temperature_step_c` first, so a drifting
//!   measurement does not rebuild the setup at every poll.
//! - **Status**: whenever an input changes, [`PassSetup::status`] (~50 us for a
//!   4-stand block) gives per span: stable or not, the worst growth exponent (1/s)
//!   and the speed margin (m/s) to the nearest band edge.
//! - **Flags** ([`SpanFlags`]): "unstable" is set as soon as a span is unstable and
//!   cleared only once it is stable with a margin of at least `hysteresis_m_s` (m/s)
//!   or no band edge in the speed range; "near tongue" is set when a stable span's
//!   margin falls below `near_tongue_m_s` and cleared once it is at least
//!   `near_tongue_m_s + hysteresis_m_s`, so a speed dithering at a band edge does not
//!   toggle the flags.
//! - **Bad input** (a configuration value outside the list, a pass number outside
//!   the schedule, a speed <= 0, a temperature outside the modulus table): the spans
//!   are published invalid (quality 0, "invalid" bit), the error is logged once with
//!   the key, the value and the allowed range, and the monitor carries on with the
//!   next value. The hysteresis state restarts after invalid input.
//! - **Stale inputs**: when the source of any input is stale or lost, the board
//!   marks the mill stale ([`crate::state::board::Board`]): every span is
//!   published invalid until the source answers again, never with frozen values.

use std::collections::BTreeMap;
use std::sync::Arc;

use millgate_config::Config;
use millgate_sim::rod::check::{PassSetup, SpanStatus};
use millgate_sim::rod::mill::RodMill;
use millgate_sim::rod::schedule::{self, Pass};
use millgate_sim::rod::RodError;

use crate::field::acquired::Acquired;
use crate::state::board::Board;
use crate::state::events::{AlarmKind, AlarmRecord};
use crate::state::results::{RodMillResults, RodSpanResults, MAX_ROD_SPANS};
use crate::state::time::UtcTime;
/// Most pass setups cached per rod mill; the cache is emptied when a new key would
/// pass it (passes x configurations x temperature steps actually seen).
pub const MAX_CACHED_SETUPS: usize = 64;

/// A rod mill the monitor cannot be built for. Each message starts with the key at
/// fault (`rod_mills[0].mill`), as the configuration's own problems do.
#[derive(Debug, thiserror::Error)]
pub enum RodSetupError {
    /// The mill file or its drive model is not valid (the message names the file,
    /// the key and the allowed range).
    #[error("rod_mills[{index}].mill: {source}")]
    Mill {
        /// Index of the rod mill in the configuration.
        index: usize,
        /// What is wrong with the file.
        #[source]
        source: RodError,
    },
    /// The schedule CSV is not valid (file, line, column).
    #[error("rod_mills[{index}].schedule: {source}")]
    Schedule {
        /// Index of the rod mill in the configuration.
        index: usize,
        /// What is wrong with the file.
        #[source]
        source: RodError,
    },
    /// The schedule has no pass.
    #[error("rod_mills[{index}].schedule: {file} has no pass (must have 1 or more rows)")]
    EmptySchedule {
        /// Index of the rod mill in the configuration.
        index: usize,
        /// The schedule file.
        file: String,
    },
    /// A configuration name is not one of the mill's drive.
    #[error(
        "rod_mills[{index}].configurations[{position}]: \"{name}\" is not allowed (must be a \
         configuration of the drive of {file}: {known})"
    )]
    UnknownConfiguration {
        /// Index of the rod mill in the configuration.
        index: usize,
        /// Position in `configurations`.
        position: usize,
        /// The name given.
        name: String,
        /// The mill file.
        file: String,
        /// The drive's configuration names, comma-separated.
        known: String,
    },
    /// The mill has more spans than the register map holds.
    #[error(
        "rod_mills[{index}].mill: {file} has {spans} spans (must have 1..={MAX_ROD_SPANS}: the \
         register map holds {MAX_ROD_SPANS} spans per rod mill)"
    )]
    TooManySpans {
        /// Index of the rod mill in the configuration.
        index: usize,
        /// The mill file.
        file: String,
        /// Its spans.
        spans: usize,
    },
}

/// The published flag state of one span.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SpanFlags {
    /// The span is unstable (held until the margin reaches the hysteresis).
    pub unstable: bool,
    /// The span is stable but near a tongue (held until the margin reaches the
    /// near-tongue margin plus the hysteresis).
    pub near_tongue: bool,
}

impl SpanFlags {
    /// The flags after `status`, with near-tongue margin `near_m_s` and hysteresis
    /// `hysteresis_m_s` (m/s; see the module docs).
    pub fn next(self, status: &SpanStatus, near_m_s: f64, hysteresis_m_s: f64) -> SpanFlags {
        if !status.stable {
            return SpanFlags {
                unstable: true,
                near_tongue: false,
            };
        }
        // Stable: the margin is the distance to the nearest band edge (None: no edge).
        let margin = status.speed_margin_m_s.unwrap_or(f64::INFINITY);
        let unstable = self.unstable && margin < hysteresis_m_s;
        let near_tongue = !unstable
            && if self.near_tongue || self.unstable {
                margin < near_m_s + hysteresis_m_s
            } else {
                margin < near_m_s
            };
        SpanFlags {
            unstable,
            near_tongue,
        }
    }
}

/// Cache key of a pass setup: pass (0-based), configuration (index into the
/// drive's), rounded temperature (multiples of the step; `None`: the schedule's).
type SetupKey = (usize, usize, Option<i64>);

/// The latest value of each input, `None` until it first arrives.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Inputs {
    configuration: Option<f64>,
    pass: Option<f64>,
    finishing_speed: Option<f64>,
    temperature: Option<f64>,
}

/// The operating point the spans were evaluated at.
#[derive(Debug, Clone, Copy)]
struct Operating {
    /// Value of the configuration input (index into `configurations`).
    configuration: u16,
    /// Pass number, 1-based.
    pass: u16,
    finishing_speed_m_s: f64,
    temperature_c: f64,
}

/// One rod mill: its inputs, cached setups and flag state.
#[derive(Debug)]
pub struct RodMonitor {
    /// `rod_mills[k]`.
    key: String,
    settings: millgate_config::RodMill,
    /// Channel names of the inputs, for messages.
    channel_names: [String; 4],
    mill: Arc<RodMill>,
    passes: Vec<Pass>,
    /// `configurations[k]` as an index into the mill's configurations.
    configurations: Vec<usize>,
    inputs: Inputs,
    /// Inputs of the last evaluation.
    evaluated: Option<Inputs>,
    setups: BTreeMap<SetupKey, Result<Arc<PassSetup>, String>>,
    flags: Vec<SpanFlags>,
    /// The last refusal logged, so a bad value is logged once, not at every poll.
    last_error: Option<String>,
    evaluations: u64,
}

/// Why the current inputs give no result: a sentence naming the key, the value and
/// the allowed range.
#[derive(Debug, Clone, PartialEq)]
struct Refused(String);

impl RodMonitor {
    /// Loads the mill and schedule files of `config.rod_mills[index]` and checks the
    /// configuration names against the mill's drive.
    pub fn new(config: &Config, index: usize) -> Result<Self, RodSetupError> {
        let settings = config.rod_mills[index].clone();
        let mill = RodMill::load(&settings.mill)
            .map_err(|source| RodSetupError::Mill { index, source })?;
        if mill.spans.len() > MAX_ROD_SPANS {
            return Err(RodSetupError::TooManySpans {
                index,
                file: mill.file.clone(),
                spans: mill.spans.len(),
            });
        }
        let passes = schedule::load(&settings.schedule)
            .map_err(|source| RodSetupError::Schedule { index, source })?;
        if passes.is_empty() {
            return Err(RodSetupError::EmptySchedule {
                index,
                file: settings.schedule.display().to_string(),
            });
        }
        let configurations = settings
            .configurations
            .iter()
            .enumerate()
            .map(|(position, name)| {
                mill.configuration(name)
                    .map(|(found, _)| found)
                    .ok_or_else(|| RodSetupError::UnknownConfiguration {
                        index,
                        position,
                        name: name.clone(),
                        file: mill.file.clone(),
                        known: mill
                            .configurations
                            .iter()
                            .map(|c| c.name.as_str())
                            .collect::<Vec<_>>()
                            .join(", "),
                    })
            })
            .collect::<Result<Vec<_>, _>>()?;
        let channel = |channel: usize| config.channels[channel].name.clone();
        let channel_names = [
            channel(settings.configuration),
            channel(settings.pass),
            channel(settings.finishing_speed),
            settings.temperature.map(channel).unwrap_or_default(),
        ];
        Ok(Self {
            key: format!("rod_mills[{index}]"),
            flags: vec![SpanFlags::default(); mill.spans.len()],
            mill: Arc::new(mill),
            passes,
            configurations,
            channel_names,
            settings,
            inputs: Inputs::default(),
            evaluated: None,
            setups: BTreeMap::new(),
            last_error: None,
            evaluations: 0,
        })
    }

    /// The mill's span names, in rolling order.
    pub(crate) fn span_names(&self) -> Vec<String> {
        self.mill
            .spans
            .iter()
            .map(|span| span.name.clone())
            .collect()
    }

    /// Pass setups cached so far.
    pub fn cached_setups(&self) -> usize {
        self.setups.len()
    }

    /// Takes process value `value` of `channel` if it is one of this mill's inputs;
    /// returns the new results when an input changed and every input is known.
    pub fn process_value(&mut self, channel: usize, value: f64) -> Option<RodMillResults> {
        let settings = &self.settings;
        let slot = if channel == settings.configuration {
            &mut self.inputs.configuration
        } else if channel == settings.pass {
            &mut self.inputs.pass
        } else if channel == settings.finishing_speed {
            &mut self.inputs.finishing_speed
        } else if Some(channel) == settings.temperature {
            &mut self.inputs.temperature
        } else {
            return None;
        };
        *slot = Some(value);
        if self.evaluated == Some(self.inputs) {
            return None;
        }
        let waiting = self.inputs.configuration.is_none()
            || self.inputs.pass.is_none()
            || self.inputs.finishing_speed.is_none()
            || (settings.temperature.is_some() && self.inputs.temperature.is_none());
        if waiting {
            return None;
        }
        self.evaluated = Some(self.inputs);
        self.evaluations += 1;
        Some(match self.evaluate() {
            Ok((operating, statuses)) => {
                self.last_error = None;
                self.results(Some(operating), Some(&statuses))
            }
            Err(Refused(message)) => {
                if self.last_error.as_ref() != Some(&message) {
                    tracing::warn!(rod_mill = %self.settings.name, error = %message, "rod mill input refused; spans marked invalid");
                    self.last_error = Some(message);
                }
                self.flags.fill(SpanFlags::default());
                self.results(None, None)
            }
        })
    }

    /// The spans' status at the current inputs.
    fn evaluate(&mut self) -> Result<(Operating, Vec<SpanStatus>), Refused> {
        let inputs = self.inputs;
        let configuration = self.integer_input(
            0,
            "configuration",
            inputs.configuration.unwrap_or(f64::NAN),
            0,
            self.configurations.len() - 1,
            &format!(
                ": {}",
                self.settings
                    .configurations
                    .iter()
                    .enumerate()
                    .map(|(k, name)| format!("{k} {name}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        )?;
        let pass = self.integer_input(
            1,
            "pass",
            inputs.pass.unwrap_or(f64::NAN),
            1,
            self.passes.len(),
            &format!(", the rows of {}", self.settings.schedule.display()),
        )?;
        let speed = inputs.finishing_speed.unwrap_or(f64::NAN);
        if !(speed.is_finite() && speed > 0.0) {
            return Err(self.refuse(2, "finishing_speed", speed, "> 0 m/s"));
        }
        let temperature_level = match (self.settings.temperature, inputs.temperature) {
            (Some(_), Some(temperature)) if temperature.is_finite() => {
                Some((temperature / self.settings.temperature_step_c).round() as i64)
            }
            (Some(_), _) => {
                let (lo, hi) = self.mill.temperature_range_c();
                return Err(self.refuse(
                    3,
                    "temperature",
                    f64::NAN,
                    &format!("within the modulus table, {lo} ..= {hi} deg C"),
                ));
            }
            (None, _) => None,
        };
        let key = (
            pass - 1,
            self.configurations[configuration],
            temperature_level,
        );
        let setup = self.setup(key)?;
        let statuses = setup.status(speed).map_err(|error| {
            Refused(format!(
                "{}.finishing_speed (channel \"{}\"): {error}",
                self.key, self.channel_names[2]
            ))
        })?;
        Ok((
            Operating {
                configuration: configuration as u16,
                pass: pass as u16,
                finishing_speed_m_s: speed,
                temperature_c: setup.pass.temperature_c,
            },
            statuses,
        ))
    }

    /// Input `which` (index into the channel names) as an integer in `lo..=hi`.
    fn integer_input(
        &self,
        which: usize,
        field: &str,
        value: f64,
        lo: usize,
        hi: usize,
        meaning: &str,
    ) -> Result<usize, Refused> {
        if value.fract() == 0.0 && value >= lo as f64 && value <= hi as f64 {
            Ok(value as usize)
        } else {
            Err(self.refuse(
                which,
                field,
                value,
                &format!("an integer {lo}..={hi}{meaning}"),
            ))
        }
    }

    fn refuse(&self, which: usize, field: &str, value: f64, allowed: &str) -> Refused {
        Refused(format!(
            "{}.{field} (channel \"{}\"): {value} is not allowed (must be {allowed})",
            self.key, self.channel_names[which]
        ))
    }

    /// The setup of `key`, from the cache or computed (and cached, refusals too).
    fn setup(&mut self, key: SetupKey) -> Result<Arc<PassSetup>, Refused> {
        if !self.setups.contains_key(&key) {
            if self.setups.len() >= MAX_CACHED_SETUPS {
                self.setups.clear();
            }
            let built = self.build_setup(key);
            self.setups.insert(key, built);
        }
        match &self.setups[&key] {
            Ok(setup) => Ok(Arc::clone(setup)),
            Err(message) => Err(Refused(message.clone())),
        }
    }

    /// The pass of the schedule with the PLC's configuration and temperature. Its
    /// own finishing speed only has to lie in the configuration's range (the live
    /// speed is given to `status`): the schedule's, clamped into that range.
    fn build_setup(
        &self,
        (pass, configuration, temperature_level): SetupKey,
    ) -> Result<Arc<PassSetup>, String> {
        let mut online = self.passes[pass].clone();
        let modes = &self.mill.configurations[configuration];
        online.configuration = modes.name.clone();
        if let Some(level) = temperature_level {
            online.temperature_c = level as f64 * self.settings.temperature_step_c;
        }
        let (lo, hi) = modes.speed_range_m_s;
        let nominal = online
            .finishing_speed_m_s
            .or_else(|| {
                online
                    .stand_speeds_m_s
                    .as_ref()
                    .and_then(|s| s.last().copied())
            })
            .unwrap_or(lo);
        let in_range = nominal.clamp(lo, hi);
        online.finishing_speed_m_s = Some(in_range);
        if let Some(speeds) = &mut online.stand_speeds_m_s {
            speeds.iter_mut().for_each(|v| *v *= in_range / nominal);
        }
        online.origin = format!(
            "{} \"{}\", pass {} ({}) in configuration {}",
            self.key, self.settings.name, online.name, online.origin, modes.name
        );
        let started = std::time::Instant::now();
        let setup = PassSetup::new(&self.mill, &online).map_err(|error| {
            let field = if matches!(&error, RodError::Pass { key, .. } if key == "temperature_c") {
                format!(".temperature (channel \"{}\")", self.channel_names[3])
            } else {
                String::new()
            };
            format!("{}{field}: {error}", self.key)
        })?;
        tracing::debug!(rod_mill = %self.settings.name, pass = %online.name, configuration = %modes.name, elapsed = ?started.elapsed(), "rod pass setup computed");
        Ok(Arc::new(setup))
    }

    /// Results at `operating` with `statuses` (both `None`: invalid input).
    fn results(
        &mut self,
        operating: Option<Operating>,
        statuses: Option<&[SpanStatus]>,
    ) -> RodMillResults {
        let (near, hysteresis) = (self.settings.near_tongue_m_s, self.settings.hysteresis_m_s);
        let spans = match statuses {
            Some(statuses) => statuses
                .iter()
                .zip(&mut self.flags)
                .map(|(status, flags)| {
                    *flags = flags.next(status, near, hysteresis);
                    RodSpanResults {
                        valid: true,
                        unstable: flags.unstable,
                        near_tongue: flags.near_tongue,
                        speed_margin_m_s: status.speed_margin_m_s,
                        worst_exponent_per_s: status.worst_exponent_per_s,
                        configuration: operating.map(|o| o.configuration),
                    }
                })
                .collect(),
            None => vec![RodSpanResults::default(); self.mill.spans.len()],
        };
        RodMillResults {
            evaluations: self.evaluations,
            input_refused: operating.is_none(),
            configuration: operating.map(|o| o.configuration),
            pass: operating.map(|o| o.pass),
            finishing_speed_m_s: operating.map(|o| o.finishing_speed_m_s),
            temperature_c: operating.map(|o| o.temperature_c),
            source_stale: false,
            spans,
        }
    }
}

/// The rod monitors of every rod mill, publishing into the results.
#[derive(Debug)]
pub(crate) struct RodAnalysis {
    monitors: Vec<RodMonitor>,
    /// The rod mills' names, for the history.
    names: Vec<String>,
    board: Arc<Board>,
}

impl RodAnalysis {
    /// Monitors for every rod mill of `config`.
    pub(crate) fn new(config: &Config, board: Arc<Board>) -> Result<Self, RodSetupError> {
        let monitors = (0..config.rod_mills.len())
            .map(|index| RodMonitor::new(config, index))
            .collect::<Result<_, _>>()?;
        Ok(Self {
            monitors,
            names: config.rod_mills.iter().map(|m| m.name.clone()).collect(),
            board,
        })
    }

    /// The monitors, in config order.
    pub(crate) fn monitors(&self) -> &[RodMonitor] {
        &self.monitors
    }

    /// Route a reader message: process values that are a rod mill's input.
    pub(crate) fn handle(&mut self, message: &Acquired) {
        let Acquired::ProcessValue { channel, value } = *message else {
            return;
        };
        for (index, monitor) in self.monitors.iter_mut().enumerate() {
            if let Some(results) = monitor.process_value(channel, value) {
                let name = &self.names[index];
                self.board.update_recorded(|published, events| {
                    if let Some(slot) = published.rod_mills.get_mut(index) {
                        // A span going unstable or near a tongue, and back, is an alarm
                        // event (the history keeps it, OPC UA sends it).
                        events.extend(AlarmRecord::flag_changes(
                            (&*slot, &results),
                            &[AlarmKind::Unstable, AlarmKind::NearTongue],
                            (name, UtcTime::now()),
                            results.worst_span().map(|(_, margin)| margin),
                        ));
                        *slot = results;
                    }
                });
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The example RSM block with a temperature channel; channels 0..4 are the
    /// configuration, pass, speed and temperature.
    fn monitor() -> RodMonitor {
        let models = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../sim/models/rod");
        let mut text = String::from(
            "name = \"rod\"\n[[sources.modbus]]\nname = \"plc\"\naddress = \"127.0.0.1:1\"\npoll_period_ms = 20\n",
        );
        for (address, name) in ["configuration", "pass", "speed", "temperature"]
            .iter()
            .enumerate()
        {
            text += &format!(
                "[[channels]]\nname = \"{name}\"\nkind = \"process_value\"\nunit = \"1\"\n\
                 source = {{ modbus = \"plc\", table = \"holding\", address = {address} }}\n"
            );
        }
        text += "[[rod_mills]]\nname = \"RSM\"\nmill = \"rsm-mill.toml\"\n\
                 schedule = \"rsm-schedule.csv\"\nconfiguration = \"configuration\"\n\
                 configurations = [\"table3\", \"fast\"]\npass = \"pass\"\n\
                 finishing_speed = \"speed\"\ntemperature = \"temperature\"\n";
        let config = millgate_config::from_toml_str(&text, "rod.toml", &models)
            .unwrap_or_else(|error| panic!("{error}"));
        RodMonitor::new(&config, 0).unwrap_or_else(|error| panic!("{error}"))
    }

    /// Feeds (configuration, pass, speed, temperature); the last results.
    fn feed(monitor: &mut RodMonitor, values: [f64; 4]) -> Option<RodMillResults> {
        let mut last = None;
        for (channel, value) in values.into_iter().enumerate() {
            last = monitor.process_value(channel, value).or(last);
        }
        last
    }

    #[test]
    fn refused_inputs_name_the_key_and_range_and_the_monitor_recovers() {
        let mut monitor = monitor();
        // Nothing until every input is known; a channel not its own is ignored.
        assert_eq!(monitor.process_value(0, 0.0), None);
        assert_eq!(monitor.process_value(7, 1.0), None);
        let good = feed(&mut monitor, [0.0, 1.0, 60.0, 950.0]).expect("evaluated");
        assert!(!good.input_refused && good.spans.len() == 3 && good.spans.iter().all(|s| s.valid));
        assert_eq!(
            (good.configuration, good.pass, good.temperature_c),
            (Some(0), Some(1), Some(950.0))
        );
        // The same inputs again: nothing to recompute.
        assert_eq!(feed(&mut monitor, [0.0, 1.0, 60.0, 950.0]), None);
        let refusals = [
            ([0.0, 9.0, 60.0, 950.0], "rod_mills[0].pass (channel \"pass\"): 9 is not allowed (must be an integer 1..=4, the rows of"),
            ([2.0, 1.0, 60.0, 950.0], "rod_mills[0].configuration (channel \"configuration\"): 2 is not allowed (must be an integer 0..=1: 0 table3, 1 fast)"),
            ([0.0, 1.0, 0.0, 950.0], "rod_mills[0].finishing_speed (channel \"speed\"): 0 is not allowed (must be > 0 m/s)"),
            ([0.0, 1.0, 60.0, 1500.0], "rod_mills[0].temperature (channel \"temperature\"): rod_mills[0] \"RSM\", pass P1"),
        ];
        for (values, expected) in refusals {
            let results = feed(&mut monitor, values).expect("evaluated");
            assert!(results.input_refused, "{values:?}");
            assert!(results.spans.iter().all(|s| !s.valid), "{values:?}");
            let message = monitor.last_error.clone().unwrap_or_default();
            assert!(message.starts_with(expected), "{message}");
            if values[3] == 1500.0 {
                assert!(
                    message.contains(
                        "temperature_c: 1500 is not allowed (must be within the modulus table"
                    ),
                    "{message}"
                );
            }
            let back = feed(&mut monitor, [0.0, 1.0, 61.0 + values[2], 950.0]).expect("evaluated");
            assert!(
                !back.input_refused && back.spans.iter().all(|s| s.valid),
                "{values:?}"
            );
        }
        // Pass P1 in table3 at 950 and at 1500 deg C (refused, cached too): the bad
        // pass and configuration are refused before any setup.
        assert_eq!(monitor.cached_setups(), 2);
    }

    fn status(stable: bool, margin: Option<f64>) -> SpanStatus {
        SpanStatus {
            span: "S1-S2".into(),
            stable,
            worst_exponent_per_s: Some(if stable { -1.0 } else { 1.0 }),
            speed_margin_m_s: margin,
        }
    }

    /// Walk a span through a band and out: the flags set at the thresholds and clear
    /// only past them plus the hysteresis.
    #[test]
    fn flags_have_hysteresis_on_both_sides() {
        let (near, hysteresis) = (2.0, 0.5);
        let mut flags = SpanFlags::default();
        let mut step = |stable, margin| {
            flags = flags.next(&status(stable, margin), near, hysteresis);
            (flags.unstable, flags.near_tongue)
        };
        assert_eq!(step(true, None), (false, false));
        assert_eq!(step(true, Some(2.2)), (false, false));
        assert_eq!(step(true, Some(1.9)), (false, true));
        // Dithering just above the threshold keeps it.
        assert_eq!(step(true, Some(2.3)), (false, true));
        assert_eq!(step(true, Some(2.5)), (false, false));
        assert_eq!(step(true, Some(0.1)), (false, true));
        assert_eq!(step(false, Some(-0.4)), (true, false));
        // Stable again, but within the hysteresis of the edge: still unstable.
        assert_eq!(step(true, Some(0.2)), (true, false));
        // Beyond the hysteresis: unstable clears, near tongue takes over.
        assert_eq!(step(true, Some(0.6)), (false, true));
        assert_eq!(step(true, Some(2.4)), (false, true));
        assert_eq!(step(true, Some(2.6)), (false, false));
        // An unstable span with no speed that helps, then a stable one without edges.
        assert_eq!(step(false, None), (true, false));
        assert_eq!(step(true, None), (false, false));
    }
}
