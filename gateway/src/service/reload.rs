//! `SIGHUP` to `millgate run` (`systemctl reload millgate`): the configuration file is
//! read and checked again, and what changed is applied where it can be without a
//! restart. Nothing in flight is touched: the readers and the analysis run on (no
//! bite, capture or sample is dropped), and the store-and-forward backlog is in the
//! history, where a restarted Sparkplug node takes it up again.
//!
//! - A file with errors is refused with them (file, line, key, allowed range): the
//!   service runs on with the configuration it has.
//! - An unchanged file (by its [`millgate_config::Config::hash`]) changes nothing.
//! - A changed file is compared section by section with the running one ([`plan`]):
//!   - applied at once: a driveline's `thresholds` (TAF and gap warning and alarm),
//!     in the analysis from its next bite on (the maintenance page, which shows them,
//!     is restarted with them); a tandem mill's chatter thresholds
//!     (`gain_thresholds`, `product_groups`, `slow_down_release`, `slow_down_hold_s`,
//!     `weld_settle_s`, `weld_alarm_factor`) from its next window on, its windows, filters and
//!     slow-down request running on (a request set stays set and clears by the new
//!     release level and hold); a driveline's `wear.horizon_days` (how far the gap's
//!     and the fatigue life's forecasts look) from its next bite on;
//!   - applied by restarting the output with its new settings: `outputs.plc`,
//!     `outputs.server`, `outputs.metrics`, `outputs.mqtt`, `outputs.web` (added,
//!     changed or removed; a new address is bound before the old output stops, and a
//!     bind that fails keeps the old output);
//!   - drivelines added after the others within `outputs.driveline_slots`, on
//!     channels already read ([`Live::Drivelines`]): checked first (the map keeps
//!     every address, the analysis builds, a `model` loads and fits its `wear`
//!     settings; the history read for the state it kept under their names, on a
//!     read-only connection of its own, a file that cannot be read refusing the
//!     reload: `resumed_from`), then the outputs that show drivelines stop, the
//!     analysis takes them once its shares in flight ended (the board grows, each resuming what a
//!     start would restore of its name before its first bite), and the outputs start
//!     again on the map
//!     with their reserved blocks (Sparkplug with a new session: their DBIRTHs); a
//!     running OPC UA server adds their nodes as it runs (its sessions kept), and the
//!     plan says so. The gap maps of one with a `model` are read from the cache or
//!     built off the analysis as at a start (`building` on the web API until they are
//!     ready; its bites meanwhile are held and folded in then);
//!   - Modbus sources appended after the others (none while CAN sources run), CAN
//!     sources appended after the others, and channels appended after the others on
//!     such a source or on a running Modbus source ([`Live::Sources`]): the analysis
//!     routes their channels, then a reader starts per source (its health, counters
//!     and outage tracking with it) and a running Modbus source's reader takes its new
//!     channels between two polls; a driveline added on such a channel starts live
//!     with it. A new channel on a running CAN source waits (its reader keeps the
//!     channels it started with);
//!   - kept as they run until a restart, each named: everything else (`name`,
//!     `cache_dir`, the sources and channels but the above, rod mills, `history`, `outputs.opcua`, a
//!     driveline's other settings (its other `wear` keys build the gap maps at the
//!     start), a tandem
//!     mill's other settings (stands, bands, windows, `k_max`, `detector`, context
//!     tags, captures), drivelines or tandem mills added (but the above), removed or
//!     reordered. A driveline added within the slots on a channel not read yet is
//!     named with "no address moves" (it takes its reserved register block at the
//!     restart) and why it waits; one beyond the slots with the blocks it
//!     moves (a new driveline block goes before the extension, tandem and rod mill
//!     blocks).
//!
//! A hang-up is never the default action of the signal (which ends the process with
//! no final PLC write and leaves its run `unclean` in the history).

use std::fmt;
use std::path::Path;

use millgate_config::{Config, Driveline, TandemMill, WearSettings};

use crate::history::query::HistoryReader;
use crate::state::events::RestoredDriveline;
use crate::state::time::UtcTime;

/// A part of the configuration that a reload applies without a restart.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Live {
    /// `outputs.plc`.
    Plc,
    /// `outputs.server`.
    Server,
    /// `outputs.metrics`.
    Metrics,
    /// `outputs.mqtt`.
    Mqtt,
    /// `outputs.web`.
    Web,
    /// Any driveline's `thresholds`.
    Thresholds,
    /// Any driveline's `wear.horizon_days` (the gap's and the fatigue life's
    /// forecasts; its other `wear` keys build the gap maps at the start).
    Horizon,
    /// Any tandem mill's chatter thresholds: `gain_thresholds`, `product_groups`, `slow_down_release`,
    /// `slow_down_hold_s`, `weld_settle_s`, `weld_alarm_factor` (what its detector's
    /// bits and slow-down request are judged by; the rest of its entry shapes its
    /// windows, filters, register block or nodes and needs a restart).
    Chatter,
    /// Drivelines added after the others within `outputs.driveline_slots`, on
    /// channels already read: the analysis takes them once its shares in flight ended, the board
    /// grows, the gap maps of those with a `model` build as at a start, and the
    /// outputs that show drivelines restart on the map with their reserved blocks.
    Drivelines,
    /// Modbus sources appended after the others (none added before the CAN sources),
    /// CAN sources appended after the others, and channels appended after the others
    /// on such a source or on a running Modbus source: the analysis routes their
    /// channels, their readers start (health, counters and outage tracking with them),
    /// a running Modbus source's reader takes its new channels between two polls, and
    /// the outputs that name sources or channels restart.
    Sources,
}

/// `running`'s tandem mill entry with the chatter thresholds ([`Live::Chatter`]) of `new`.
fn with_chatter_thresholds(running: &TandemMill, new: &TandemMill) -> TandemMill {
    TandemMill {
        gain_thresholds: new.gain_thresholds.clone(),
        product_groups: new.product_groups.clone(),
        slow_down_release: new.slow_down_release,
        slow_down_hold_s: new.slow_down_hold_s,
        weld_settle_s: new.weld_settle_s,
        weld_alarm_factor: new.weld_alarm_factor,
        ..running.clone()
    }
}

/// What a reload changes: the applied parts (their keys) and what they touch, and the
/// parts that keep running as they are until a restart (their keys, and why).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Plan {
    /// The keys applied, e.g. `outputs.web`, `drivelines.F1.thresholds`.
    pub applied: Vec<String>,
    /// What the applied keys touch.
    pub live: Vec<Live>,
    /// The keys a restart applies.
    pub needs_restart: Vec<String>,
}

impl Plan {
    /// `running` with the parts this plan applies taken from `new`: what the service
    /// runs once it is applied.
    pub fn applied_to(&self, running: &Config, new: &Config) -> Config {
        let mut config = running.clone();
        let outputs = (&mut config.outputs, &new.outputs);
        for live in &self.live {
            match live {
                Live::Plc => outputs.0.plc.clone_from(&outputs.1.plc),
                Live::Server => outputs.0.server.clone_from(&outputs.1.server),
                Live::Metrics => outputs.0.metrics.clone_from(&outputs.1.metrics),
                Live::Mqtt => outputs.0.mqtt.clone_from(&outputs.1.mqtt),
                Live::Web => outputs.0.web.clone_from(&outputs.1.web),
                Live::Thresholds => {
                    for (driveline, changed) in config.drivelines.iter_mut().zip(&new.drivelines) {
                        driveline.thresholds = changed.thresholds;
                    }
                }
                Live::Horizon => {
                    for (driveline, changed) in config.drivelines.iter_mut().zip(&new.drivelines) {
                        driveline.wear.horizon_days = changed.wear.horizon_days;
                    }
                }
                Live::Chatter => {
                    for (mill, changed) in config.tandem_mills.iter_mut().zip(&new.tandem_mills) {
                        *mill = with_chatter_thresholds(mill, changed);
                    }
                }
                Live::Sources => {
                    config.modbus_sources.clone_from(&new.modbus_sources);
                    config.can_sources.clone_from(&new.can_sources);
                    config.channels.clone_from(&new.channels);
                }
                Live::Drivelines => {
                    let added = new.drivelines.get(running.drivelines.len()..);
                    config
                        .drivelines
                        .extend(added.into_iter().flatten().cloned());
                }
            }
        }
        if self.needs_restart.is_empty() {
            config.hash.clone_from(&new.hash);
        }
        config
    }
}

impl Plan {
    /// Say in the entry of each driveline added live (`drivelines.F2 (added in ...)`)
    /// what it resumes from the history (`resumed`), or that it starts empty when
    /// there is no history to resume it from; a name the history does not know starts
    /// empty, as a new driveline does at a start, and its entry says nothing more.
    pub(crate) fn note_resumed(&mut self, resumed: &Resumed) {
        let notes = resumed.names.iter().filter_map(|name| {
            let note = match resumed.drivelines.iter().find(|d| d.name == *name) {
                Some(state) => {
                    let results = &state.results;
                    let last = results
                        .last_bite_unix_ms
                        .map(|ms| format!(", last bite {}", UtcTime::from_unix_ms(ms)))
                        .unwrap_or_default();
                    format!(
                        "its state resumed from the history: bite counter {}{last}",
                        results.bite_counter
                    )
                }
                None => resumed.otherwise.clone()?,
            };
            Some((name, note))
        });
        for (name, note) in notes {
            let entry = format!("drivelines.{name} (added in ");
            if let Some(applied) = self.applied.iter_mut().find(|a| a.starts_with(&entry)) {
                // Inside its parentheses.
                applied.pop();
                applied.push_str(&format!("; {note})"));
            }
        }
    }
}

/// What the history holds of the drivelines a reload adds live ([`resumed_from`]).
#[derive(Debug, Clone, Default, PartialEq)]
pub(crate) struct Resumed {
    /// The drivelines added, by name.
    pub names: Vec<String>,
    /// The state the history kept of those it knows by name, as a start restores it.
    pub drivelines: Vec<RestoredDriveline>,
    /// Why the others start empty when there is nothing to resume them from (no
    /// `[history]`, its file absent); `None` when the history was read.
    pub otherwise: Option<String>,
}

/// The state the history file at `path` (`None` without `[history]`) kept of the
/// drivelines `names` a reload adds, as a start would restore it: read on a
/// read-only connection of its own (the writer thread owns the read-write one; in WAL
/// mode neither waits for the other), on the caller's thread (a blocking one: the
/// analysis does not wait for it). `Err` says why the file cannot be read (busy,
/// damaged, not a history): the reload is then refused, since a driveline the file
/// knows would otherwise publish a bite counter below the one it kept.
pub(crate) fn resumed_from(path: Option<&Path>, names: &[String]) -> Result<Resumed, String> {
    let empty = |why: String| Resumed {
        names: names.to_vec(),
        drivelines: Vec::new(),
        otherwise: Some(why),
    };
    let Some(path) = path else {
        return Ok(empty(
            "no [history] to resume it from: it starts empty".into(),
        ));
    };
    if !path.exists() {
        return Ok(empty(format!(
            "the history file {} is absent: it starts empty",
            path.display()
        )));
    }
    let refused = |error| {
        format!(
            "the history cannot be read to resume the state of {} ({error}): nothing is \
             added and the running drivelines run on; reload again once the file can be \
             read",
            names.join(", ")
        )
    };
    let reader = HistoryReader::open(path).map_err(refused)?;
    let drivelines = names
        .iter()
        .filter_map(|name| reader.driveline_state(name).transpose())
        .collect::<Result<Vec<_>, _>>()
        .map_err(refused)?;
    Ok(Resumed {
        names: names.to_vec(),
        drivelines,
        otherwise: None,
    })
}

/// What a reload request found, and did.
#[derive(Debug, Clone, PartialEq)]
pub enum Reload {
    /// The file has errors (their report): nothing changes.
    Refused(String),
    /// The file's settings are the running ones.
    Unchanged,
    /// The file differs: what was applied and what needs a restart.
    Changed(Plan),
}

impl Reload {
    /// `applied`, `refused`, `needs_restart` (something is kept until a restart, even
    /// when other parts were applied) or `unchanged`: the outcome `/metrics` counts.
    pub fn outcome(&self) -> &'static str {
        match self {
            Reload::Refused(_) => "refused",
            Reload::Unchanged => "unchanged",
            Reload::Changed(plan) if plan.needs_restart.is_empty() => "applied",
            Reload::Changed(_) => "needs_restart",
        }
    }
}

impl fmt::Display for Reload {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Reload::Refused(errors) => write!(
                f,
                "reload refused: the configuration has errors; the service runs on with the \
                 one it has: {errors}"
            ),
            Reload::Unchanged => write!(f, "reload: the configuration is unchanged"),
            Reload::Changed(plan) => {
                write!(f, "reload: ")?;
                if !plan.applied.is_empty() {
                    write!(f, "applied {}", plan.applied.join(", "))?;
                }
                if !plan.needs_restart.is_empty() {
                    if !plan.applied.is_empty() {
                        write!(f, "; ")?;
                    }
                    write!(
                        f,
                        "changed {}: applying them needs a restart (systemctl restart \
                         millgate); the service runs on with them as it started",
                        plan.needs_restart.join(", ")
                    )?;
                }
                Ok(())
            }
        }
    }
}

/// The file at `path` checked and compared with `running` (nothing applied).
pub fn reload(running: &Config, path: &Path) -> Reload {
    match millgate_config::load(path) {
        Err(errors) => Reload::Refused(errors.to_string()),
        Ok(new) => compare(running, &new),
    }
}

/// What differs between `running` and `new`: unchanged, or the plan.
pub fn compare(running: &Config, new: &Config) -> Reload {
    if running.hash == new.hash && running == new {
        return Reload::Unchanged;
    }
    let plan = plan(running, new);
    match plan.applied.is_empty() && plan.needs_restart.is_empty() {
        // Only what the hash sees and the settings do not (a default written out).
        true => Reload::Unchanged,
        false => Reload::Changed(plan),
    }
}

/// What of `new` can be applied to a service running `running`, and what needs a
/// restart, by key.
pub fn plan(running: &Config, new: &Config) -> Plan {
    let mut plan = Plan::default();
    let (old, out) = (&running.outputs, &new.outputs);
    let live = [
        ("outputs.plc", old.plc != out.plc, Live::Plc),
        ("outputs.server", old.server != out.server, Live::Server),
        ("outputs.metrics", old.metrics != out.metrics, Live::Metrics),
        ("outputs.mqtt", old.mqtt != out.mqtt, Live::Mqtt),
        ("outputs.web", old.web != out.web, Live::Web),
    ];
    // The edge node keeps its bdSeq and backlog in the history: without the history
    // the service opened at its start, a new node waits for a restart.
    let mqtt_waits = out.mqtt.is_some() && running.history.is_none();
    for (key, changed, part) in live {
        if changed && part == Live::Mqtt && mqtt_waits {
            plan.needs_restart
                .push(format!("{key} (its [history] opens at the start)"));
        } else if changed {
            plan.applied.push(key.to_owned());
            plan.live.push(part);
        }
    }
    let restart = [
        ("name", running.name != new.name),
        ("cache_dir", running.cache_dir != new.cache_dir),
        ("log_format", running.log_format != new.log_format),
        ("analysis.workers", running.analysis != new.analysis),
        ("rod_mills", running.rod_mills != new.rod_mills),
        ("outputs.opcua", old.opcua != out.opcua),
        (
            "outputs.driveline_slots (the tandem and rod mill blocks and the extension \
             blocks move)",
            running.driveline_slots() != new.driveline_slots()
                && old.driveline_slots != out.driveline_slots,
        ),
        ("history", running.history != new.history),
    ];
    plan.needs_restart.extend(
        restart
            .iter()
            .filter(|(_, changed)| *changed)
            .map(|(key, _)| (*key).to_owned()),
    );
    match sources_added(running, new) {
        Ok(added) if added.is_empty() => {}
        Ok(added) => {
            plan.applied.extend(added);
            plan.live.push(Live::Sources);
            let names: Vec<String> = new
                .sources()
                .skip(running.sources().count())
                .map(|source| source.name().to_owned())
                .collect();
            if out.opcua.is_some() && !names.is_empty() {
                plan.needs_restart.push(format!(
                    "outputs.opcua (shows {} after a restart: its nodes are built at the \
                     start)",
                    names.join(", ")
                ));
            }
        }
        Err(why) => {
            let inputs = [
                ("sources", running.modbus_sources != new.modbus_sources),
                ("can_sources", running.can_sources != new.can_sources),
                ("channels", running.channels != new.channels),
            ];
            let changed: Vec<&str> = inputs
                .iter()
                .filter(|(_, changed)| *changed)
                .map(|(key, _)| *key)
                .collect();
            plan.needs_restart
                .push(format!("{} ({why})", changed.join(", ")));
        }
    }
    drivelines(running, new, &mut plan);
    tandem_mills(&running.tandem_mills, &new.tandem_mills, &mut plan);
    plan
}

/// Into `plan`, the tandem mills' changes: the chatter thresholds ([`Live::Chatter`]) apply; any other
/// change, or a mill added, removed or moved, needs a restart.
fn tandem_mills(running: &[TandemMill], new: &[TandemMill], plan: &mut Plan) {
    let names = |mills: &[TandemMill]| mills.iter().map(|m| m.name.clone()).collect::<Vec<_>>();
    if names(running) != names(new) {
        plan.needs_restart
            .push("tandem_mills (added, removed or reordered)".to_owned());
        return;
    }
    let mut chatter = false;
    for (old, new) in running.iter().zip(new) {
        let live = [
            (
                "gain_thresholds",
                old.gain_thresholds != new.gain_thresholds,
            ),
            ("product_groups", old.product_groups != new.product_groups),
            (
                "slow_down_release",
                old.slow_down_release != new.slow_down_release,
            ),
            (
                "slow_down_hold_s",
                old.slow_down_hold_s != new.slow_down_hold_s,
            ),
            ("weld_settle_s", old.weld_settle_s != new.weld_settle_s),
            (
                "weld_alarm_factor",
                old.weld_alarm_factor != new.weld_alarm_factor,
            ),
        ];
        for (key, _) in live.iter().filter(|(_, changed)| *changed) {
            plan.applied
                .push(format!("tandem_mills.{}.{key}", new.name));
            chatter = true;
        }
        let settings = [
            ("stands", old.stands != new.stands),
            (
                "chatter_band_hz",
                old.chatter_band_hz != new.chatter_band_hz,
            ),
            ("window_s", old.window_s != new.window_s),
            ("k_max", old.k_max != new.k_max),
            ("detector", old.detector != new.detector),
            (
                "reference_band_hz",
                old.reference_band_hz != new.reference_band_hz,
            ),
            ("gain_window_s", old.gain_window_s != new.gain_window_s),
            ("context", old.context != new.context),
            (
                "capture_before_s",
                old.capture_before_s != new.capture_before_s,
            ),
            (
                "capture_after_s",
                old.capture_after_s != new.capture_after_s,
            ),
            ("capture_max_s", old.capture_max_s != new.capture_max_s),
            ("identification", old.identification != new.identification),
        ];
        let otherwise = with_chatter_thresholds(old, new) != *new;
        name_restarts(
            plan,
            &format!("tandem_mills.{}", new.name),
            &settings,
            otherwise,
        );
    }
    if chatter {
        plan.live.push(Live::Chatter);
    }
}

/// Into `plan`'s restarts, the keys of `entry` (`drivelines.F1`) whose `settings`
/// changed, or when none did and the entry differs `otherwise` (a key added to it and
/// not named), the entry.
fn name_restarts(plan: &mut Plan, entry: &str, settings: &[(&str, bool)], otherwise: bool) {
    let named: Vec<String> = settings
        .iter()
        .filter(|(_, changed)| *changed)
        .map(|(key, _)| format!("{entry}.{key}"))
        .collect();
    if named.is_empty() && otherwise {
        plan.needs_restart.push(entry.to_owned());
    }
    plan.needs_restart.extend(named);
}

/// Into `plan`, the drivelines' changes: thresholds and `wear.horizon_days` apply, and
/// drivelines added after the others within `outputs.driveline_slots` on channels
/// already read ([`Live::Drivelines`]); any other change, or a
/// driveline added otherwise, removed or moved, needs a restart (one added within the
/// slots takes its reserved register block: no address moves, and the plan says so).
fn drivelines(running_config: &Config, new_config: &Config, plan: &mut Plan) {
    let new = &new_config.drivelines;
    let running = &running_config.drivelines;
    let names = |drivelines: &[Driveline]| -> Vec<String> {
        drivelines.iter().map(|d| d.name.clone()).collect()
    };
    let (old_names, new_names) = (names(running), names(new));
    if old_names != new_names {
        let added: Vec<&str> = new_names
            .iter()
            .filter(|name| !old_names.contains(name))
            .map(String::as_str)
            .collect();
        let removed: Vec<&str> = old_names
            .iter()
            .filter(|name| !new_names.contains(name))
            .map(String::as_str)
            .collect();
        let mut what = Vec::new();
        let slots = running_config.driveline_slots();
        let appended = new_names.starts_with(&old_names);
        if !added.is_empty() && appended && new_names.len() <= slots {
            match added_waits(running_config, new_config) {
                None => added_live(running_config, new_config, plan),
                Some(why) => what.push(format!(
                    "added {} in the register blocks outputs.driveline_slots ({slots}) \
                     reserves: no address moves; {why}",
                    added.join(", ")
                )),
            }
        } else if !added.is_empty() {
            what.push(format!(
                "added {} (beyond the {slots} driveline blocks of the register map: a new \
                 block moves the extension, tandem and rod mill blocks; reserve them with \
                 outputs.driveline_slots)",
                added.join(", ")
            ));
        }
        if !removed.is_empty() {
            what.push(format!("removed {}", removed.join(", ")));
        }
        if what.is_empty() && !plan.live.contains(&Live::Drivelines) {
            what.push("reordered".to_owned());
        }
        if !what.is_empty() {
            plan.needs_restart
                .push(format!("drivelines ({})", what.join("; ")));
            return;
        }
    }
    let (mut thresholds, mut horizon) = (false, false);
    for (old, new) in running.iter().zip(new) {
        if old.thresholds != new.thresholds {
            plan.applied
                .push(format!("drivelines.{}.thresholds", new.name));
            thresholds = true;
        }
        let (old_wear, new_wear) = (&old.wear, &new.wear);
        if old_wear.horizon_days != new_wear.horizon_days {
            plan.applied
                .push(format!("drivelines.{}.wear.horizon_days", new.name));
            horizon = true;
        }
        let wear_maps = WearSettings {
            horizon_days: old_wear.horizon_days,
            ..new_wear.clone()
        };
        let settings = [
            ("torque", old.torque != new.torque),
            ("metal_in_stand", old.metal_in_stand != new.metal_in_stand),
            ("extra_channels", old.extra_channels != new.extra_channels),
            ("model", old.model != new.model),
            ("bite", old.bite != new.bite),
            ("wear", old.wear != wear_maps),
            ("fatigue", old.fatigue != new.fatigue),
            ("context", old.context != new.context),
            (
                "pool_speed_range_mpm",
                old.pool_speed_range_mpm != new.pool_speed_range_mpm,
            ),
            ("identification", old.identification != new.identification),
        ];
        let applied = Driveline {
            thresholds: new.thresholds,
            wear: new.wear.clone(),
            ..old.clone()
        };
        name_restarts(
            plan,
            &format!("drivelines.{}", new.name),
            &settings,
            applied != *new,
        );
    }
    if thresholds {
        plan.live.push(Live::Thresholds);
    }
    if horizon {
        plan.live.push(Live::Horizon);
    }
}

/// Why the drivelines added (after the others, within the slots) cannot start live:
/// their channels are not the ones read (the readers start channels at a start).
/// `None` when they can (with a `model` too: its gap maps build as at a start).
fn added_waits(running: &Config, new: &Config) -> Option<String> {
    let why = sources_added(running, new).err()?;
    Some(format!(
        "{why}: a driveline starts live only on channels already read or added with it"
    ))
}

/// The keys of the sources and channels `new` appends to `running`'s, which start
/// live ([`Live::Sources`]; empty when the inputs are the running ones), or why they
/// wait for a restart. Modbus and CAN sources appended after the others start a reader
/// each; a channel appended on a running Modbus source is handed to its reader, which
/// takes it between two polls (its poll in flight and its other channels untouched).
/// Waits: a running source or channel changed, moved or removed (its reader keeps the
/// settings it started with), a channel appended on a running CAN source (its reader
/// keeps the frames it decodes), and a Modbus source added while CAN sources run
/// (sources count Modbus first, then CAN: it would move their status bits).
fn sources_added(running: &Config, new: &Config) -> Result<Vec<String>, String> {
    if !new.can_sources.starts_with(&running.can_sources) {
        return Err(
            "a running CAN source changed or moved: its reader keeps the settings it \
             started with"
                .into(),
        );
    }
    if !new.modbus_sources.starts_with(&running.modbus_sources) {
        return Err(
            "a running Modbus source changed or moved: its reader keeps the settings it \
             started with"
                .into(),
        );
    }
    let modbus = &new.modbus_sources[running.modbus_sources.len()..];
    if !modbus.is_empty() && !running.can_sources.is_empty() {
        return Err(
            "a Modbus source added while CAN sources run would move their status bits \
             (sources count Modbus first, then CAN)"
                .into(),
        );
    }
    if !new.channels.starts_with(&running.channels) {
        return Err(
            "a channel read changed, moved or was removed: its reader keeps the channels \
             it started with"
                .into(),
        );
    }
    let can = &new.can_sources[running.can_sources.len()..];
    let mut added: Vec<String> = modbus
        .iter()
        .map(|source| &source.name)
        .chain(can.iter().map(|source| &source.name))
        .map(|name| format!("sources.{name} (its reader started live)"))
        .collect();
    let running_modbus = running.modbus_sources.len();
    for (index, channel) in new.channels.iter().enumerate().skip(running.channels.len()) {
        let name = &channel.name;
        match running_source_of(running, new, index) {
            None => added.push(format!("channels.{name} (on a source added live)")),
            Some(source) if source < running_modbus => {
                let source = &running.modbus_sources[source].name;
                added.push(format!(
                    "channels.{name} (on the running source {source}: its reader takes it \
                     between two polls)"
                ));
            }
            Some(source) => {
                let source = &running.can_sources[source - running_modbus].name;
                return Err(format!(
                    "channels.{name} is on the running CAN source {source}: its reader \
                     keeps the channels it started with"
                ));
            }
        }
    }
    Ok(added)
}

/// The index in `running`'s [`Config::sources`] of the source `new`'s channel
/// `channel` is read from, when that source runs (`None`: a source `new` adds).
fn running_source_of(running: &Config, new: &Config, channel: usize) -> Option<usize> {
    match new.channels[channel].source {
        millgate_config::ChannelSource::Can { source, .. } => {
            (source < running.can_sources.len()).then(|| running.modbus_sources.len() + source)
        }
        _ => Some(new.source_of_channel(channel)).filter(|&s| s < running.modbus_sources.len()),
    }
}

/// Into `plan`, the drivelines `new` adds after `running`'s applied live
/// ([`Live::Drivelines`]), each in the register block the slots reserve (one with a
/// `model` says its gap maps build as the service runs); a running OPC UA server adds
/// their nodes as it runs, and the plan names that.
fn added_live(running: &Config, new: &Config, plan: &mut Plan) {
    let first = running.drivelines.len();
    let added = new.drivelines.get(first..).unwrap_or_default();
    for (k, driveline) in (first..).zip(added) {
        let maps = match driveline.model {
            Some(_) => "; its gap maps read from the cache or built as the service runs",
            None => "",
        };
        plan.applied.push(format!(
            "drivelines.{} (added in the register block of driveline_slot{}: no address \
             moves{maps})",
            driveline.name,
            k + 1
        ));
    }
    plan.live.push(Live::Drivelines);
    // A server added by this reload waits for a restart ("outputs.opcua"), and then
    // shows them from its start.
    if running.outputs.opcua.is_some() && new.outputs.opcua.is_some() {
        let names: Vec<&str> = added.iter().map(|d| d.name.as_str()).collect();
        plan.applied.push(format!(
            "outputs.opcua (the nodes of {} added as the server runs)",
            names.join(", ")
        ));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The demo's configuration with its model named by its full path, so the file
    /// can sit in a scratch folder.
    fn demo() -> String {
        let examples = concat!(env!("CARGO_MANIFEST_DIR"), "/../config/examples");
        include_str!("../../../config/examples/demo.toml").replace(
            "model = \"table2-adjusted.toml\"",
            &format!("model = \"{examples}/table2-adjusted.toml\""),
        )
    }

    fn changed(plan: Reload) -> Plan {
        match plan {
            Reload::Changed(plan) => plan,
            other => panic!("expected a change: {other:?}"),
        }
    }

    #[test]
    fn a_reload_names_errors_what_it_applies_and_what_needs_a_restart() {
        let folder = std::env::temp_dir().join(format!("millgate-reload-{}", std::process::id()));
        std::fs::create_dir_all(&folder).unwrap();
        let path = folder.join("mill.toml");
        std::fs::write(&path, demo()).unwrap();
        let running = millgate_config::load(&path).unwrap();
        assert_eq!(reload(&running, &path), Reload::Unchanged);
        // A comment does not count.
        std::fs::write(&path, format!("# edited\n{}", demo())).unwrap();
        assert_eq!(reload(&running, &path), Reload::Unchanged);

        // A threshold applies.
        let text = demo().replace("taf_alarm = 2.6", "taf_alarm = 2.8");
        std::fs::write(&path, &text).unwrap();
        let outcome = reload(&running, &path);
        assert_eq!(outcome.outcome(), "applied");
        let plan = changed(outcome.clone());
        assert_eq!(plan.live, [Live::Thresholds]);
        let name = &running.drivelines[0].name;
        assert_eq!(plan.applied, [format!("drivelines.{name}.thresholds")]);
        let new = millgate_config::load(&path).unwrap();
        let applied = plan.applied_to(&running, &new);
        assert_eq!(applied, new, "everything applied: the new configuration");
        assert_eq!(compare(&applied, &new), Reload::Unchanged);
        assert!(
            outcome
                .to_string()
                .starts_with("reload: applied drivelines."),
            "{outcome}"
        );

        // A threshold and a bite setting: the one applies, the other waits.
        let text = text.replace("threshold_knm = 20.0", "threshold_knm = 25.0");
        std::fs::write(&path, &text).unwrap();
        let outcome = reload(&running, &path);
        assert_eq!(outcome.outcome(), "needs_restart");
        let plan = changed(outcome.clone());
        assert_eq!(plan.needs_restart, [format!("drivelines.{name}.bite")]);
        assert_eq!(plan.live, [Live::Thresholds]);
        let new = millgate_config::load(&path).unwrap();
        let applied = plan.applied_to(&running, &new);
        assert_eq!(
            applied.drivelines[0].thresholds,
            new.drivelines[0].thresholds
        );
        assert_eq!(applied.drivelines[0].bite, running.drivelines[0].bite);
        assert_eq!(applied.hash, running.hash, "not all applied: the old hash");
        // Reloading the same file again applies nothing new and names the rest again.
        let again = changed(compare(&applied, &new));
        assert!(
            again.applied.is_empty() && again.live.is_empty(),
            "{again:?}"
        );
        assert_eq!(again.needs_restart, plan.needs_restart);
        let said = outcome.to_string();
        assert!(said.contains("applied drivelines.") && said.contains("needs a restart"));

        // A driveline added needs a restart, and says why.
        let added = running.drivelines.len() + 1;
        let mut bigger = running.clone();
        let mut copy = running.drivelines[0].clone();
        copy.name = "F9".into();
        bigger.drivelines.push(copy);
        bigger.hash = "other".into();
        let plan = changed(compare(&running, &bigger));
        assert_eq!(bigger.drivelines.len(), added);
        assert!(plan.applied.is_empty());
        assert!(
            plan.needs_restart[0].starts_with("drivelines (added F9")
                && plan.needs_restart[0].contains("moves the extension"),
            "{plan:?}"
        );
        // Within the reserved slots, on a channel read, it is added live, in its
        // reserved block: with a model (its gap maps built as the service runs), and
        // without.
        let mut reserved = running.clone();
        reserved.outputs.driveline_slots = Some(added);
        let mut grown = bigger.clone();
        grown.outputs.driveline_slots = Some(added);
        let model = grown.drivelines[added - 1].model.clone();
        assert!(model.is_some());
        let maps = "; its gap maps read from the cache or built as the service runs";
        for (model, said) in [(model, maps), (None, "")] {
            grown.drivelines[added - 1].model = model;
            let plan = changed(compare(&reserved, &grown));
            assert!(plan.needs_restart.is_empty(), "{plan:?}");
            assert_eq!(plan.live, [Live::Drivelines]);
            assert_eq!(
                plan.applied,
                [format!(
                    "drivelines.F9 (added in the register block of driveline_slot{added}: \
                     no address moves{said})"
                )]
            );
        }
        let plan = changed(compare(&reserved, &grown));
        let applied = plan.applied_to(&reserved, &grown);
        assert_eq!(applied, grown, "everything applied: the new configuration");
        // A running OPC UA server adds its nodes, and the plan says so.
        let with_opcua = format!("{}\n[outputs.opcua]\nbind = \"127.0.0.1:4840\"\n", demo());
        let examples =
            std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../config/examples"));
        let opcua = millgate_config::from_toml_str(&with_opcua, "demo.toml", examples)
            .unwrap()
            .outputs
            .opcua;
        assert!(opcua.is_some());
        let (mut served, mut grown_served) = (reserved.clone(), grown.clone());
        served.outputs.opcua.clone_from(&opcua);
        grown_served.outputs.opcua = opcua;
        let plan = changed(compare(&served, &grown_served));
        assert_eq!(plan.live, [Live::Drivelines]);
        assert!(plan.needs_restart.is_empty(), "{plan:?}");
        assert_eq!(
            plan.applied.last().map(String::as_str),
            Some("outputs.opcua (the nodes of F9 added as the server runs)")
        );
        // On a channel appended on a running source, it starts live: the source's
        // reader takes the channel between two polls.
        let mut on_new_channel = grown.clone();
        let mut channel = on_new_channel.channels[grown.drivelines[0].torque].clone();
        channel.name = "spindle_f9".into();
        on_new_channel.channels.push(channel);
        on_new_channel.drivelines[added - 1].torque = on_new_channel.channels.len() - 1;
        let plan = changed(compare(&reserved, &on_new_channel));
        assert!(plan.needs_restart.is_empty(), "{plan:?}");
        assert_eq!(plan.live, [Live::Sources, Live::Drivelines]);
        let daq = &reserved.modbus_sources[0].name;
        assert_eq!(
            plan.applied[0],
            format!(
                "channels.spindle_f9 (on the running source {daq}: its reader takes it \
                 between two polls)"
            )
        );
        assert_eq!(plan.applied_to(&reserved, &on_new_channel), on_new_channel);
        // A channel read changed beside it: everything on the inputs waits, and the
        // driveline on the new channel with them.
        let mut moved = on_new_channel.clone();
        moved.channels[0].scale *= 2.0;
        let plan = changed(compare(&reserved, &moved));
        assert!(plan.live.is_empty(), "{plan:?}");
        assert!(
            plan.needs_restart
                .iter()
                .any(|key| key.starts_with("channels (a channel read changed")),
            "{plan:?}"
        );
        assert!(
            plan.needs_restart
                .iter()
                .any(|key| key.contains("added F9") && key.contains("channels already read")),
            "{plan:?}"
        );
        // On a Modbus source added with it (a reader of its own), it starts live too.
        let mut on_new_source = grown.clone();
        let mut source = on_new_source.modbus_sources[0].clone();
        source.name = "daq9".into();
        on_new_source.modbus_sources.push(source);
        let mut channel = on_new_source.channels[grown.drivelines[0].torque].clone();
        channel.name = "spindle_f9".into();
        let millgate_config::ChannelSource::ModbusBlock { table, base, .. } = channel.source else {
            panic!("the demo's torque is a Modbus block: {:?}", channel.source);
        };
        let source = on_new_source.modbus_sources.len() - 1;
        channel.source = millgate_config::ChannelSource::ModbusBlock {
            source,
            table,
            base,
        };
        on_new_source.channels.push(channel);
        on_new_source.drivelines[added - 1].torque = on_new_source.channels.len() - 1;
        let plan = changed(compare(&reserved, &on_new_source));
        assert!(plan.needs_restart.is_empty(), "{plan:?}");
        assert_eq!(plan.live, [Live::Sources, Live::Drivelines]);
        assert_eq!(
            plan.applied[..2],
            [
                "sources.daq9 (its reader started live)",
                "channels.spindle_f9 (on a source added live)"
            ]
        );
        assert_eq!(plan.applied_to(&reserved, &on_new_source), on_new_source);
        // A running source changed beside it: everything waits, and says why.
        let mut changed_too = on_new_source.clone();
        changed_too.modbus_sources[0].timeout *= 2;
        let plan = changed(compare(&reserved, &changed_too));
        assert!(plan.live.is_empty(), "{plan:?}");
        assert!(
            plan.needs_restart
                .iter()
                .any(|key| key.starts_with("sources, channels (a running Modbus source changed")),
            "{plan:?}"
        );
        // The slots themselves move the blocks after them.
        let plan = changed(compare(&running, &reserved));
        assert_eq!(plan.needs_restart.len(), 1, "{plan:?}");
        assert!(
            plan.needs_restart[0].starts_with("outputs.driveline_slots"),
            "{plan:?}"
        );

        let broken = demo().replace("taf_alarm = 2.6", "taf_alarm = -1.0");
        std::fs::write(&path, broken).unwrap();
        let refused = reload(&running, &path);
        let Reload::Refused(errors) = &refused else {
            panic!("a file with errors is refused: {refused:?}");
        };
        assert!(
            errors.contains("mill.toml") && errors.contains("taf_alarm"),
            "{errors}"
        );
        assert_eq!(refused.outcome(), "refused");
        assert!(
            refused.to_string().starts_with("reload refused"),
            "{refused}"
        );
        std::fs::remove_dir_all(&folder).unwrap();
    }

    #[test]
    fn a_tandem_mills_thresholds_apply_and_its_windows_need_a_restart() {
        let examples =
            std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../config/examples"));
        let text = include_str!("../../../config/examples/tandem-5stand.toml");
        let running = millgate_config::from_toml_str(text, "tandem.toml", examples).unwrap();
        let mut new = running.clone();
        new.hash = "other".into();
        new.tandem_mills[0].gain_thresholds[2] = 9.0;
        new.tandem_mills[0].weld_alarm_factor = 3.0;
        let plan = changed(compare(&running, &new));
        assert_eq!(plan.live, [Live::Chatter]);
        assert_eq!(
            plan.applied,
            [
                "tandem_mills.TCM 2030.gain_thresholds",
                "tandem_mills.TCM 2030.weld_alarm_factor"
            ]
        );
        assert!(plan.needs_restart.is_empty(), "{plan:?}");
        assert_eq!(plan.applied_to(&running, &new), new);

        // A window change waits for a restart; the thresholds beside it apply.
        new.tandem_mills[0].window_s = 1.0;
        new.tandem_mills[0].slow_down_hold_s = 2.0;
        let plan = changed(compare(&running, &new));
        assert_eq!(plan.live, [Live::Chatter]);
        assert_eq!(plan.needs_restart, ["tandem_mills.TCM 2030.window_s"]);
        let applied = plan.applied_to(&running, &new);
        let (mill, was) = (&applied.tandem_mills[0], &running.tandem_mills[0]);
        assert_eq!(mill.window_s, was.window_s);
        assert_eq!(mill.gain_thresholds, new.tandem_mills[0].gain_thresholds);
        assert_eq!(mill.slow_down_hold_s, 2.0);
        assert_eq!(applied.hash, running.hash);

        // A mill renamed (its register block and nodes named by it) waits.
        let mut renamed = running.clone();
        renamed.hash = "other".into();
        renamed.tandem_mills[0].name = "TCM 2".into();
        let plan = changed(compare(&running, &renamed));
        assert!(plan.live.is_empty(), "{plan:?}");
        assert_eq!(
            plan.needs_restart,
            ["tandem_mills (added, removed or reordered)"]
        );
    }

    #[test]
    fn the_wear_horizon_applies_and_the_maps_grid_needs_a_restart() {
        let examples =
            std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../config/examples"));
        let running = millgate_config::from_toml_str(&demo(), "demo.toml", examples).unwrap();
        let name = running.drivelines[0].name.clone();
        let mut new = running.clone();
        new.hash = "other".into();
        new.drivelines[0].wear.horizon_days = 90.0;
        let plan = changed(compare(&running, &new));
        assert_eq!(plan.live, [Live::Horizon]);
        assert_eq!(
            plan.applied,
            [format!("drivelines.{name}.wear.horizon_days")]
        );
        assert!(plan.needs_restart.is_empty(), "{plan:?}");
        assert_eq!(plan.applied_to(&running, &new), new);

        new.drivelines[0].wear.max_gap_mrad = 6.0;
        let plan = changed(compare(&running, &new));
        assert_eq!(plan.live, [Live::Horizon]);
        assert_eq!(plan.needs_restart, [format!("drivelines.{name}.wear")]);
        let applied = plan.applied_to(&running, &new);
        assert_eq!(applied.drivelines[0].wear.horizon_days, 90.0);
        assert_eq!(
            applied.drivelines[0].wear.max_gap_mrad,
            running.drivelines[0].wear.max_gap_mrad
        );
        // Keys added after the list above are named too (was: a changed nameplate or
        // context tag reloaded as "unchanged").
        let mut tagged = running.clone();
        tagged.hash = "other".into();
        tagged.drivelines[0].pool_speed_range_mpm = Some((10.0, 900.0));
        let plan = changed(compare(&running, &tagged));
        assert_eq!(
            plan.needs_restart,
            [format!("drivelines.{name}.pool_speed_range_mpm")]
        );
    }

    /// The hot mill example (Modbus and CAN sources), its DBC found beside it.
    fn hot_mill() -> Config {
        let examples =
            std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../config/examples"));
        let text = include_str!("../../../config/examples/hot-mill.toml");
        millgate_config::from_toml_str(text, "hot-mill.toml", examples)
            .unwrap_or_else(|error| panic!("{error}"))
    }

    /// `channel` (a CAN channel) read from CAN source `index`.
    fn on_can_source(channel: &mut millgate_config::Channel, index: usize) {
        match &mut channel.source {
            millgate_config::ChannelSource::Can { source, .. } => *source = index,
            other => panic!("not a CAN channel: {other:?}"),
        }
    }

    #[test]
    fn a_can_source_appended_starts_live_and_a_changed_one_waits() {
        let running = hot_mill();
        assert_eq!(
            running.can_sources.len(),
            1,
            "the example has one CAN source"
        );
        // A second CAN source, with a channel on it, after the others.
        let mut new = running.clone();
        new.hash = "other".into();
        let mut can = new.can_sources[0].clone();
        can.name = "stand_can2".into();
        can.interface = "vcan1".into();
        new.can_sources.push(can);
        let on_can = new
            .channels
            .iter()
            .position(|c| matches!(c.source, millgate_config::ChannelSource::Can { .. }))
            .unwrap();
        let mut channel = new.channels[on_can].clone();
        channel.name = "f2_roll_force".into();
        on_can_source(&mut channel, 1);
        new.channels.push(channel.clone());
        let plan = changed(compare(&running, &new));
        assert!(plan.needs_restart.is_empty(), "{plan:?}");
        assert_eq!(plan.live, [Live::Sources]);
        assert_eq!(
            plan.applied,
            [
                "sources.stand_can2 (its reader started live)",
                "channels.f2_roll_force (on a source added live)"
            ]
        );
        assert_eq!(plan.applied_to(&running, &new), new);

        // A channel appended on the running CAN source waits, and says why.
        let mut on_running = running.clone();
        on_running.hash = "other".into();
        on_can_source(&mut channel, 0);
        on_running.channels.push(channel);
        let plan = changed(compare(&running, &on_running));
        assert!(plan.live.is_empty(), "{plan:?}");
        assert_eq!(
            plan.needs_restart,
            [
                "channels (channels.f2_roll_force is on the running CAN source stand_can: its \
                 reader keeps the channels it started with)"
            ]
        );

        // The running CAN source changed: it waits.
        let mut changed_can = new.clone();
        changed_can.can_sources[0].interface = "vcan9".into();
        let plan = changed(compare(&running, &changed_can));
        assert!(plan.live.is_empty(), "{plan:?}");
        assert_eq!(
            plan.needs_restart,
            [
                "can_sources, channels (a running CAN source changed or moved: its reader \
                 keeps the settings it started with)"
            ]
        );

        // A Modbus source added while the CAN source runs would move its status bit.
        let mut modbus = running.clone();
        modbus.hash = "other".into();
        let mut source = modbus.modbus_sources[0].clone();
        source.name = "daq2".into();
        modbus.modbus_sources.push(source);
        let plan = changed(compare(&running, &modbus));
        assert!(plan.live.is_empty(), "{plan:?}");
        assert!(
            plan.needs_restart[0].starts_with("sources (a Modbus source added while CAN"),
            "{plan:?}"
        );

        // A channel appended on a running Modbus source beside the CAN source starts.
        let mut on_daq = running.clone();
        on_daq.hash = "other".into();
        let mut channel = on_daq.channels[0].clone();
        channel.name = "spindle_middle".into();
        on_daq.channels.push(channel);
        let plan = changed(compare(&running, &on_daq));
        assert!(plan.needs_restart.is_empty(), "{plan:?}");
        assert_eq!(plan.live, [Live::Sources]);
        assert_eq!(
            plan.applied,
            [
                "channels.spindle_middle (on the running source daq1: its reader takes it \
              between two polls)"
            ]
        );
    }

    #[test]
    fn an_output_removed_applies() {
        let examples =
            std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../config/examples"));
        let running = millgate_config::from_toml_str(&demo(), "demo.toml", examples).unwrap();
        assert!(
            running.outputs.server.is_some(),
            "the demo has an HMI server"
        );
        let mut new = running.clone();
        new.hash = "other".into();
        new.outputs.server = None;
        let plan = changed(compare(&running, &new));
        assert_eq!(plan.live, [Live::Server]);
        assert_eq!(plan.applied, ["outputs.server"]);
        assert!(plan.needs_restart.is_empty());
        let applied = plan.applied_to(&running, &new);
        assert_eq!(applied.outputs, new.outputs);
        assert_eq!(applied.hash, "other");

        // An edge node needs the history the service opened at its start.
        let text = format!(
            "{}\n[outputs.mqtt]\nbroker = \"mq1:1883\"\ngroup_id = \"g\"\nnode_id = \"n\"\n\
             \n[history]\npath = \"history.db\"\n",
            demo()
        );
        let with_history = millgate_config::from_toml_str(&text, "demo.toml", examples).unwrap();
        let plan = changed(compare(&running, &with_history));
        assert!(plan.live.iter().all(|part| *part != Live::Mqtt), "{plan:?}");
        assert!(
            plan.needs_restart
                .contains(&"outputs.mqtt (its [history] opens at the start)".to_owned()),
            "{plan:?}"
        );
    }

    /// A scratch folder for `name`'s files, empty.
    fn folder(name: &str) -> std::path::PathBuf {
        let folder =
            std::env::temp_dir().join(format!("millgate-reload-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&folder);
        std::fs::create_dir_all(&folder).unwrap();
        folder
    }

    /// A plan that adds F2 and F3 live, as `added_live` words it.
    fn adding_f2_f3() -> Plan {
        let added = |name: &str, slot: usize| {
            format!(
                "drivelines.{name} (added in the register block of driveline_slot{slot}: no \
                 address moves)"
            )
        };
        Plan {
            applied: vec![added("F2", 2), added("F3", 3)],
            live: vec![Live::Drivelines],
            needs_restart: Vec::new(),
        }
    }

    #[test]
    fn a_driveline_added_live_resumes_what_the_history_kept_of_its_name() {
        let folder = folder("resume");
        let path = folder.join("history.db");
        let mut connection = crate::history::writer::connect(&path).unwrap();
        let kept = crate::state::results::DrivelineResults {
            bite_counter: 41,
            last_bite_unix_ms: Some(1_777_939_198_250),
            wear_trend: Some(0.25),
            ..Default::default()
        };
        let transaction = connection.transaction().unwrap();
        crate::history::figures::upsert_state(&transaction, "F2", UtcTime::from_unix_ms(1), &kept)
            .unwrap();
        transaction.commit().unwrap();
        let names = ["F2".to_owned(), "F3".to_owned()];
        let resumed = resumed_from(Some(&path), &names).unwrap();
        assert_eq!(resumed.otherwise, None);
        let [f2] = &resumed.drivelines[..] else {
            panic!("{resumed:?}");
        };
        assert_eq!((f2.name.as_str(), f2.results.bite_counter), ("F2", 41));
        assert_eq!(f2.results.wear_trend, Some(0.25));
        assert!(f2.results.restored);
        // F2's entry says what it resumed; F3, a name the file does not know, starts
        // empty as a new driveline does, and its entry says nothing more.
        let mut plan = adding_f2_f3();
        plan.note_resumed(&resumed);
        assert_eq!(
            plan.applied[0],
            "drivelines.F2 (added in the register block of driveline_slot2: no address \
             moves; its state resumed from the history: bite counter 41, last bite \
             2026-05-04T23:59:58.250Z)"
        );
        assert_eq!(plan.applied[1], adding_f2_f3().applied[1]);

        // While another connection holds the file locked, the reload is refused at
        // once, saying so (nothing waits: the running drivelines run on).
        connection
            .pragma_update(None, "locking_mode", "EXCLUSIVE")
            .unwrap();
        connection
            .execute("UPDATE driveline_state SET gap_trend = NULL", [])
            .unwrap();
        let busy = resumed_from(Some(&path), &names).unwrap_err();
        assert!(
            busy.starts_with("the history cannot be read to resume the state of F2, F3 (")
                && busy.contains("locked")
                && busy.ends_with("reload again once the file can be read"),
            "{busy}"
        );
        drop(connection);
        assert_eq!(resumed_from(Some(&path), &names).unwrap(), resumed);
        std::fs::remove_dir_all(&folder).unwrap();
    }

    #[test]
    fn a_driveline_added_live_without_a_history_to_read_starts_empty_or_is_refused() {
        let names = ["F2".to_owned(), "F3".to_owned()];
        // No [history], or its file absent: nothing to resume, and both entries say
        // they start empty.
        let folder = folder("no-history");
        let absent = folder.join("history.db");
        for (path, why) in [
            (
                None,
                "no [history] to resume it from: it starts empty".to_owned(),
            ),
            (
                Some(absent.as_path()),
                format!(
                    "the history file {} is absent: it starts empty",
                    absent.display()
                ),
            ),
        ] {
            let resumed = resumed_from(path, &names).unwrap();
            assert!(resumed.drivelines.is_empty(), "{resumed:?}");
            let mut plan = adding_f2_f3();
            plan.note_resumed(&resumed);
            for (entry, name) in plan.applied.iter().zip(&names) {
                assert!(
                    entry.starts_with(&format!("drivelines.{name} (added")),
                    "{entry}"
                );
                assert!(
                    entry.ends_with(&format!("no address moves; {why})")),
                    "{entry}"
                );
            }
        }
        // A file that is no history: refused with the reason (a start would not
        // restore from it either).
        std::fs::write(
            &absent,
            "not a database, but long enough for SQLite to look",
        )
        .unwrap();
        let refused = resumed_from(Some(&absent), &names).unwrap_err();
        assert!(refused.contains(&absent.display().to_string()), "{refused}");
        assert!(refused.contains("nothing is added"), "{refused}");
        std::fs::remove_dir_all(&folder).unwrap();
    }
}
