//! Shared fixtures for millgate's end-to-end tests.

use std::time::{Duration, Instant};

/// Poll `done` every 20 ms until it holds; panic naming `what` after `limit`.
pub async fn wait_for(what: &str, limit: Duration, mut done: impl FnMut() -> bool) {
    let start = Instant::now();
    while !done() {
        assert!(start.elapsed() < limit, "{what}: not within {limit:?}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}
