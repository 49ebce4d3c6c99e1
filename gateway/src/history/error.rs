//! Why the history file cannot be used, in words an operator can act on.

use std::path::PathBuf;

use super::schema;

/// Why the history file cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum HistoryError {
    /// SQLite refused to open or use the file.
    #[error("history {}: {}", path.display(), explain(source))]
    Sqlite {
        /// The file.
        path: PathBuf,
        /// SQLite's error.
        #[source]
        source: rusqlite::Error,
    },
    /// The path names a folder, not a file.
    #[error("history {}: a folder, not a history file (give the file, e.g. {})",
        path.display(), path.join("history.db").display())]
    Folder {
        /// The folder.
        path: PathBuf,
    },
    /// The schema could not be brought up to date.
    #[error("history {}: {source}", path.display())]
    Schema {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: schema::SchemaError,
    },
    /// A query's argument is outside its allowed range.
    #[error("history query: {name} = {value} is out of range ({allowed})")]
    Argument {
        /// The argument's name.
        name: &'static str,
        /// The value given.
        value: String,
        /// What is allowed.
        allowed: String,
    },
    /// A stored capture cannot be read (its meta or samples are damaged, or written
    /// by a newer millgate).
    #[error("history {}: {message}", path.display())]
    Capture {
        /// The file.
        path: PathBuf,
        /// What is wrong, naming the capture.
        message: String,
    },
    /// The driveline is neither configured in any run recorded in the file nor has
    /// bites in it.
    #[error("history {}: no driveline \"{name}\" in the file", path.display())]
    UnknownDriveline {
        /// The file.
        path: PathBuf,
        /// The name asked for.
        name: String,
    },
}

impl HistoryError {
    /// Whether the failure may pass with time (a lock another process holds, the
    /// disk, the file system, permissions), unlike a file that can never be this
    /// millgate's history (damaged, another application's, a newer schema) or a bad
    /// query.
    pub(crate) fn may_pass(&self) -> bool {
        let sqlite_may_pass = |source: &rusqlite::Error| {
            !matches!(
                source.sqlite_error_code(),
                Some(rusqlite::ErrorCode::NotADatabase | rusqlite::ErrorCode::DatabaseCorrupt)
            )
        };
        match self {
            HistoryError::Sqlite { source, .. } => sqlite_may_pass(source),
            HistoryError::Schema {
                source: schema::SchemaError::Sqlite(source),
                ..
            } => sqlite_may_pass(source),
            _ => false,
        }
    }
}

/// [`schema::check_owner`] as the history's error for the file at `path`: SQLite's own
/// failure (a corrupt file, say) explained as such, another application's file as a
/// schema error.
pub(super) fn check_file_owner(
    connection: &rusqlite::Connection,
    path: &std::path::Path,
) -> Result<(), HistoryError> {
    schema::check_owner(connection).map_err(|error| match error {
        schema::SchemaError::Sqlite(source) => HistoryError::Sqlite {
            path: path.to_path_buf(),
            source,
        },
        source => HistoryError::Schema {
            path: path.to_path_buf(),
            source,
        },
    })
}

/// SQLite's message, with what it means for the operator where the code says more.
pub(crate) fn explain(error: &rusqlite::Error) -> String {
    use rusqlite::ffi::ErrorCode;
    let hint = match error.sqlite_error_code() {
        Some(ErrorCode::DiskFull) => {
            " (the disk is full: free space, or lower history.max_size_mb)"
        }
        Some(ErrorCode::ReadOnly) => {
            " (the file or its folder is read-only: the service's user must be able to write both)"
        }
        Some(ErrorCode::CannotOpen) => {
            " (cannot create or open the file: does its folder exist and is it writable?)"
        }
        Some(ErrorCode::NotADatabase) | Some(ErrorCode::DatabaseCorrupt) => {
            " (the file is not a readable SQLite history: move it aside to start a new one)"
        }
        Some(ErrorCode::PermissionDenied) => " (permission denied)",
        _ => "",
    };
    format!("{error}{hint}")
}
