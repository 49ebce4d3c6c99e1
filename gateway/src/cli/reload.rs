//! `millgate reload`: ask a running `millgate run` to reload its configuration file, as
//! SIGHUP (and `systemctl reload millgate`, the unit's `ExecReload`) does. The service
//! is found by the pid file it keeps with `millgate run --pid-file FILE`; a pid that is
//! not a running `millgate` (a stale file) is refused rather than signalled. With
//! `--config`, the file is checked first and a file with errors is reported here, with
//! nothing sent. What the service applied, and what needs a restart, is in its log and
//! counted on `/metrics` (`millgate_config_reloads_total`).

use std::path::{Path, PathBuf};

use anyhow::Context;

/// `millgate reload`'s arguments.
#[derive(Debug, clap::Args)]
pub struct ReloadArgs {
    /// The pid file of the service (`millgate run --pid-file FILE`).
    #[arg(long)]
    pub pid_file: PathBuf,
    /// Check this configuration file (the one the service runs) before asking: a
    /// file with errors is reported and the service is not asked.
    #[arg(long)]
    pub config: Option<PathBuf>,
}

/// Check `--config` when given, then send SIGHUP to the service of the pid file; what
/// was done, as a sentence.
pub fn run(args: &ReloadArgs) -> anyhow::Result<String> {
    if let Some(config) = &args.config {
        millgate_config::load(config)?;
    }
    let pid = service_pid(&args.pid_file)?;
    let process = rustix::process::Pid::from_raw(pid)
        .with_context(|| format!("{}: pid {pid} is not a process id", args.pid_file.display()))?;
    rustix::process::kill_process(process, rustix::process::Signal::HUP).with_context(|| {
        format!(
            "cannot signal millgate (pid {pid} from {})",
            args.pid_file.display()
        )
    })?;
    Ok(format!(
        "asked millgate (pid {pid}) to reload its configuration: its log says what it \
         applied and what needs a restart (/metrics counts millgate_config_reloads_total)"
    ))
}

/// The pid in `pid_file`, when it is a running `millgate`.
fn service_pid(pid_file: &Path) -> anyhow::Result<i32> {
    let text = std::fs::read_to_string(pid_file).with_context(|| {
        format!(
            "{}: cannot read the pid file (is `millgate run --pid-file {}` running?)",
            pid_file.display(),
            pid_file.display()
        )
    })?;
    let pid: i32 = text.trim().parse().map_err(|_| {
        anyhow::anyhow!(
            "{}: {:?} is not a process id",
            pid_file.display(),
            text.trim()
        )
    })?;
    // A pid file left by a service that was killed may name another process now.
    let name = std::fs::read_to_string(format!("/proc/{pid}/comm")).unwrap_or_default();
    anyhow::ensure!(
        name.trim_end() == "millgate",
        "{}: pid {pid} is not a running millgate (a stale pid file?)",
        pid_file.display()
    );
    Ok(pid)
}

/// The pid file of `millgate run --pid-file`: written (whole, by a rename) at start,
/// removed when the service ends.
#[derive(Debug)]
pub struct PidFile(PathBuf);

impl PidFile {
    /// Write this process' id into `path`.
    pub fn write(path: &Path) -> anyhow::Result<Self> {
        let mut partial = path.as_os_str().to_owned();
        partial.push(".partial");
        let partial = PathBuf::from(partial);
        std::fs::write(&partial, format!("{}\n", std::process::id()))
            .and_then(|()| std::fs::rename(&partial, path))
            .with_context(|| format!("{}: cannot write the pid file", path.display()))?;
        Ok(Self(path.to_owned()))
    }
}

impl Drop for PidFile {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}
