//! The `millgate` command line under test: run to its end, or started as a service
//! that is killed when its guard drops.

use std::path::Path;
use std::process::{Child, Command, Output, Stdio};

/// The `millgate` binary: `Millgate(env!("CARGO_BIN_EXE_millgate"))` in the gateway's
/// integration tests and benches (cargo sets that variable for the tests of the
/// package that builds the binary only).
#[derive(Debug, Clone, Copy)]
pub struct Millgate(pub &'static str);

impl Millgate {
    /// `millgate` with no arguments yet, as a [`Command`].
    pub fn command(self) -> Command {
        Command::new(self.0)
    }

    /// `millgate args`, run to its end (no standard input).
    pub fn run(self, args: &[&str]) -> Output {
        self.command()
            .args(args)
            .stdin(Stdio::null())
            .output()
            .expect("run millgate")
    }

    /// `millgate capture export` of F1's bite `bite` from `db` to `out` as `format`:
    /// the file written (checked to exist; a CSV's header JSON beside it too).
    pub fn export_bite(self, db: &Path, out: &Path, bite: u32, format: &str) -> String {
        let bite = bite.to_string();
        let output = self.run(&[
            "capture",
            "export",
            "--db",
            db.to_str().unwrap(),
            "--driveline",
            "F1",
            "--bite",
            &bite,
            "--format",
            format,
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(output.status.success(), "{}", text(&output));
        let printed = String::from_utf8_lossy(&output.stdout).into_owned();
        let files: Vec<&str> = printed.lines().collect();
        let path = files[0].to_owned();
        assert!(Path::new(&path).is_file(), "{path}");
        if format == "csv" {
            let sidecar = Path::new(&path).with_extension("json");
            assert_eq!(files, [path.as_str(), sidecar.to_str().unwrap()]);
            assert!(sidecar.is_file(), "{}", sidecar.display());
        } else {
            assert_eq!(files.len(), 1, "{printed}");
        }
        path
    }
}

/// What a run printed: its standard output, then its standard error.
pub fn text(output: &Output) -> String {
    String::from_utf8_lossy(&output.stdout).to_string() + &String::from_utf8_lossy(&output.stderr)
}

/// A child process (`millgate run`, a peer) killed and reaped when dropped, so a
/// failing test leaves no process behind; derefs to the [`Child`].
#[derive(Debug)]
pub struct KillOnDrop(pub Child);

impl std::ops::Deref for KillOnDrop {
    type Target = Child;
    fn deref(&self) -> &Child {
        &self.0
    }
}

impl std::ops::DerefMut for KillOnDrop {
    fn deref_mut(&mut self) -> &mut Child {
        &mut self.0
    }
}

impl KillOnDrop {
    /// Wait for the child to end and collect what it wrote to its piped stdout and
    /// stderr, as [`Child::wait_with_output`] does, the guard kept: a test that fails
    /// before the child ends still kills it.
    pub fn wait_with_output(&mut self) -> std::io::Result<Output> {
        use std::io::Read;
        let (stdout, stderr) = (self.0.stdout.take(), self.0.stderr.take());
        // Both pipes read at once: a child blocked writing one while the other is read
        // would never end.
        let stderr = std::thread::spawn(move || {
            let mut bytes = Vec::new();
            stderr.map_or(Ok(0), |mut pipe| pipe.read_to_end(&mut bytes))?;
            std::io::Result::Ok(bytes)
        });
        let mut stdout_bytes = Vec::new();
        if let Some(mut pipe) = stdout {
            pipe.read_to_end(&mut stdout_bytes)?;
        }
        let stderr = stderr.join().expect("the stderr reader")?;
        Ok(Output {
            status: self.0.wait()?,
            stdout: stdout_bytes,
            stderr,
        })
    }
}

impl Drop for KillOnDrop {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Send SIGHUP to process `pid` (`systemctl reload`: `millgate run` reloads its
/// configuration file).
pub fn hang_up(pid: u32) {
    let sent = Command::new("kill")
        .args(["-HUP", &pid.to_string()])
        .status()
        .unwrap();
    assert!(sent.success());
}

/// Terminate `service` as systemd would, and check it stopped cleanly.
pub fn terminate(service: &mut Child) {
    let term = Command::new("kill")
        .args(["-TERM", &service.id().to_string()])
        .status()
        .unwrap();
    assert!(term.success());
    let status = service.wait().unwrap();
    assert!(status.success(), "{status:?}");
}
