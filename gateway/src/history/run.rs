//! What the history records about a run at its start: millgate's version, the
//! configuration's name and hash, and each driveline's settings (for reports; a reload that
//! changes thresholds adds them again, [`insert_settings`]).

/// What the history records about this run at its start.
#[derive(Debug, Clone)]
pub struct RunInfo {
    /// millgate's version, stored with the run.
    pub version: String,
    /// The configuration's `name`.
    pub config_name: String,
    /// The configuration's hash ([`millgate_config::Config::hash`]).
    pub config_hash: String,
    /// Each driveline's settings (table `driveline_settings`).
    pub drivelines: Vec<DrivelineSettings>,
}

/// A driveline's settings as the history keeps them for reports.
#[derive(Debug, Clone, PartialEq)]
pub struct DrivelineSettings {
    /// The driveline's name.
    pub name: String,
    /// TAF warning threshold.
    pub taf_warning: f64,
    /// TAF alarm threshold.
    pub taf_alarm: f64,
    /// The driveline model file, as configured.
    pub model: Option<String>,
    /// The gap diagnosis' warning threshold, mrad; `None` without a model (no gap
    /// diagnosis).
    pub gap_warning_mrad: Option<f64>,
    /// The gap diagnosis' alarm threshold, mrad; `None` without a model.
    pub gap_alarm_mrad: Option<f64>,
}

impl RunInfo {
    /// The run of `config` with this millgate's version.
    pub fn of(config: &millgate_config::Config) -> Self {
        Self {
            version: env!("CARGO_PKG_VERSION").to_owned(),
            config_name: config.name.clone(),
            config_hash: config.hash.clone(),
            drivelines: config
                .drivelines
                .iter()
                .map(DrivelineSettings::of)
                .collect(),
        }
    }
}

impl DrivelineSettings {
    /// `driveline`'s settings as the history keeps them.
    pub fn of(driveline: &millgate_config::Driveline) -> Self {
        Self {
            name: driveline.name.clone(),
            taf_warning: driveline.thresholds.taf_warning,
            taf_alarm: driveline.thresholds.taf_alarm,
            model: driveline
                .model
                .as_ref()
                .map(|path| path.display().to_string()),
            // The gap diagnosis runs only with a model.
            gap_warning_mrad: driveline
                .model
                .as_ref()
                .map(|_| driveline.thresholds.gap_warning_mrad),
            gap_alarm_mrad: driveline
                .model
                .as_ref()
                .map(|_| driveline.thresholds.gap_alarm_mrad),
        }
    }
}

/// Insert `drivelines`' settings of run `run_id` in effect from `time` (the run's
/// start, or a reload that changed them).
pub(crate) fn insert_settings(
    connection: &rusqlite::Connection,
    run_id: i64,
    time: &str,
    drivelines: &[DrivelineSettings],
) -> rusqlite::Result<()> {
    for driveline in drivelines {
        connection
            .prepare_cached(
                "INSERT INTO driveline_settings (run_id, time, driveline, taf_warning, taf_alarm,
                 model, gap_warning_mrad, gap_alarm_mrad)
             VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8)",
            )?
            .execute(rusqlite::params![
                run_id,
                time,
                driveline.name,
                driveline.taf_warning,
                driveline.taf_alarm,
                driveline.model,
                driveline.gap_warning_mrad,
                driveline.gap_alarm_mrad
            ])?;
    }
    Ok(())
}
