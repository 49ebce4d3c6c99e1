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

/// Write zeros into the new file `filler` until its file system is full (a small
/// tmpfs); panics unless the write that stopped failed with ENOSPC.
pub fn fill_file_system(filler: &std::path::Path) {
    use std::io::Write;
    let mut file = std::fs::File::create(filler).unwrap();
    let block = vec![0u8; 64 * 1024];
    let full = loop {
        if let Err(error) = file.write_all(&block) {
            break error;
        }
    };
    assert_eq!(full.raw_os_error(), Some(28), "ENOSPC: {full}");
}
