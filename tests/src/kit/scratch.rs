//! Scratch folders: `tempfile`'s, a fresh name each (no clash between tests, runs or
//! processes), removed with what they hold when dropped, also when a test fails.

pub use tempfile::TempDir;

/// A new empty folder `millgate-<tag>-XXXXXX` under the system's temporary folder;
/// removed when the returned guard drops. Created with the default mode (umask), as
/// `std::fs::create_dir` does: services the tests start as other users can enter it.
pub fn scratch(tag: &str) -> TempDir {
    tempfile::Builder::new()
        .prefix(&format!("millgate-{tag}-"))
        .tempdir()
        .expect("a scratch folder under the temporary folder")
}
