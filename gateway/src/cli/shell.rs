//! The command line's conventions: shell completions (`millgate completions SHELL`,
//! clap_complete), manual pages (`millgate man [--out DIR]`, clap_mangen) and the
//! exit status every command follows ([`EXIT_STATUS`]), which `millgate --help`, the
//! manual page and docs/usage.md state, and how every command prints ([`print()`]): a
//! reader that closes the pipe (`millgate figures | head -1`) ends the command
//! quietly with status 0, as `millgate history` always did, never with a panic.
//!
//! ```text
//! millgate completions bash > /etc/bash_completion.d/millgate
//! millgate completions zsh > "${fpath[1]}/_millgate"
//! millgate man | man -l -                  # the manual page of millgate
//! millgate man --out /usr/local/share/man/man1   # millgate.1 and one per command
//! ```

use std::io::Write;
use std::path::{Path, PathBuf};

/// Arguments of `millgate completions`.
#[derive(Debug, Clone, clap::Args)]
pub struct CompletionsArgs {
    /// The shell to complete for.
    #[arg(value_enum)]
    pub shell: clap_complete::Shell,
}

/// Arguments of `millgate man`.
#[derive(Debug, Clone, clap::Args)]
pub struct ManArgs {
    /// Write millgate.1 and a page per command (millgate-check.1, millgate-sim-modes.1,
    /// ...) into this folder (created when missing) instead of printing millgate.1.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// The exit status of every command, as (status, meaning).
pub const EXIT_STATUS: [(&str, &str); 4] = [
    (
        "0",
        "success: the command did what it was asked (check: the configuration is valid, \
         warnings or not; run: stopped by SIGINT or SIGTERM; --help, --version), or the \
         reader of its output closed the pipe before the end (`millgate figures | head`: \
         the command stops writing, quietly)",
    ),
    (
        "1",
        "failure, the reason on stderr: the configuration has problems (check), a file \
         cannot be read or written, the service could not start or ended by itself (run), \
         the input has no usable result",
    ),
    (
        "2",
        "usage error, from the argument parser: an unknown command or option, a missing \
         or invalid argument (the usage on stderr)",
    ),
    (
        "101",
        "a panic: a bug in millgate (please report it with the message)",
    ),
];

/// Write `text` to stdout and flush it. A reader that closed the pipe is an
/// `ErrorKind::BrokenPipe` error, which `main` ends quietly with status 0
/// ([`is_broken_pipe`]); `print!` would panic there (Rust ignores SIGPIPE, so a write
/// to a closed pipe fails instead of killing the process).
pub fn print(text: &str) -> std::io::Result<()> {
    print_bytes(text.as_bytes())
}

/// Write `bytes` to stdout and flush them, as [`print()`].
pub fn print_bytes(bytes: &[u8]) -> std::io::Result<()> {
    let mut out = std::io::stdout().lock();
    out.write_all(bytes)?;
    out.flush()
}

/// Whether `error` is a write to a closed pipe (directly or through serde_json): the
/// reader of stdout went (`| head`), which ends a command quietly with status 0.
pub fn is_broken_pipe(error: &anyhow::Error) -> bool {
    let broken = Some(std::io::ErrorKind::BrokenPipe);
    error.chain().any(|cause| {
        cause
            .downcast_ref::<std::io::Error>()
            .map(std::io::Error::kind)
            == broken
            || cause
                .downcast_ref::<serde_json::Error>()
                .and_then(serde_json::Error::io_error_kind)
                == broken
    })
}

/// [`EXIT_STATUS`] as the paragraph ending `millgate --help`.
pub fn exit_status_help() -> String {
    let mut text = String::from("Exit status:\n");
    for (status, meaning) in EXIT_STATUS {
        text.push_str(&format!("  {status:>3}  {meaning}\n"));
    }
    text
}

/// The completion script of `command` for `shell`.
pub fn completions(mut command: clap::Command, shell: clap_complete::Shell) -> Vec<u8> {
    let name = command.get_name().to_owned();
    let mut script = Vec::new();
    clap_complete::generate(shell, &mut command, name, &mut script);
    script
}

/// The manual page of `command` (roff): name, synopsis, description, options, the
/// commands, and the exit status.
pub fn man_page(command: clap::Command) -> std::io::Result<Vec<u8>> {
    let man = clap_mangen::Man::new(command.disable_help_subcommand(true));
    let mut page = Vec::new();
    man.render_title(&mut page)?;
    man.render_name_section(&mut page)?;
    man.render_synopsis_section(&mut page)?;
    man.render_description_section(&mut page)?;
    man.render_options_section(&mut page)?;
    man.render_subcommands_section(&mut page)?;
    writeln!(page, ".SH \"EXIT STATUS\"")?;
    for (status, meaning) in EXIT_STATUS {
        writeln!(page, ".TP\n{status}\n{}", meaning.replace('-', "\\-"))?;
    }
    man.render_version_section(&mut page)?;
    Ok(page)
}

/// Write `command`'s manual page and one per command below it into `folder`; the
/// files written.
pub fn write_man_pages(command: clap::Command, folder: &Path) -> anyhow::Result<Vec<PathBuf>> {
    std::fs::create_dir_all(folder)
        .map_err(|e| anyhow::anyhow!("{}: cannot create the folder: {e}", folder.display()))?;
    let mut command = command.disable_help_subcommand(true);
    command.build();
    let root = folder.join(format!("{}.1", command.get_name()));
    std::fs::write(&root, man_page(command.clone())?)
        .map_err(|e| anyhow::anyhow!("{}: cannot write: {e}", root.display()))?;
    let mut written = vec![root];
    // The commands' pages: clap_mangen names each by its display name
    // (millgate-sim-modes.1).
    fn below(
        command: &clap::Command,
        folder: &Path,
        written: &mut Vec<PathBuf>,
    ) -> anyhow::Result<()> {
        for sub in command.get_subcommands().filter(|s| !s.is_hide_set()) {
            let path = clap_mangen::Man::new(sub.clone())
                .generate_to(folder)
                .map_err(|e| anyhow::anyhow!("{}: cannot write: {e}", folder.display()))?;
            written.push(path);
            below(sub, folder, written)?;
        }
        Ok(())
    }
    below(&command, folder, &mut written)?;
    Ok(written)
}
