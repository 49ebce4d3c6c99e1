//! The analysis' bounded pool: a driveline's share of the messages that may take a
//! bite's analysis (and the tandem and rod mills' share) runs on one of `workers`
//! persistent threads, and says so when it is done ([`Finished`]); the analysis
//! task does not wait for it, but takes up the next messages meanwhile (a share for
//! a driveline still being analysed waits for it: `super::flight`). A slow job so
//! delays only its own driveline.
//!
//! The threads are rayon's (`ThreadPool::spawn`): started once, at the first job,
//! and kept, so a job costs the wake-up of an idle thread rather than the start of a
//! new one (some tens of microseconds, more on a loaded machine, hundreds of times a
//! second). Nothing queues without bound: each driveline and the mills have at most
//! one job in flight, and the finished jobs' channel at most one message per job.

use std::sync::mpsc;
use std::sync::OnceLock;

/// A pool of `workers` analysis threads, started when first needed.
#[derive(Debug)]
pub(crate) struct Pool {
    workers: usize,
    /// The threads (`None`: they could not be started, every share runs inline).
    threads: OnceLock<Option<rayon::ThreadPool>>,
}

impl Pool {
    /// A pool of `workers` threads (at least 1; with 1, every job runs inline on the
    /// calling thread and no thread is started).
    pub(crate) fn new(workers: usize) -> Self {
        Self {
            workers: workers.max(1),
            threads: OnceLock::new(),
        }
    }

    /// The threads that run jobs, started at the first call: `None` with one worker
    /// (every job runs on the calling thread) or when they could not be started.
    pub(crate) fn threads(&self) -> Option<&rayon::ThreadPool> {
        if self.workers == 1 {
            return None;
        }
        self.threads
            .get_or_init(|| {
                let built = rayon::ThreadPoolBuilder::new()
                    .num_threads(self.workers)
                    .thread_name(|i| format!("analysis-{i}"))
                    .build();
                built
                    .inspect_err(|error| {
                        tracing::error!(%error, workers = self.workers, "the analysis pool's threads did not start: the analysis runs on one thread")
                    })
                    .ok()
            })
            .as_ref()
    }
}

/// Jobs' ends: each job in flight sends what it gives once done, and wakes the
/// analysis task waiting on [`Self::woken`]. A job that panics sends its panic, which
/// the analysis task resumes when it takes that end (as a job run on its own thread
/// would panic there; rayon's default for a spawned job's panic is to abort).
#[derive(Debug)]
pub(crate) struct Finished<T> {
    sender: mpsc::Sender<std::thread::Result<T>>,
    receiver: mpsc::Receiver<std::thread::Result<T>>,
    wake: std::sync::Arc<tokio::sync::Notify>,
}

impl<T: Send + 'static> Finished<T> {
    pub(crate) fn new() -> Self {
        let (sender, receiver) = mpsc::channel();
        Self {
            sender,
            receiver,
            wake: std::sync::Arc::new(tokio::sync::Notify::new()),
        }
    }

    /// Run `job` on `threads`; what it gives is sent here once it is done.
    pub(crate) fn spawn(
        &self,
        threads: &rayon::ThreadPool,
        job: impl FnOnce() -> T + Send + 'static,
    ) {
        let (sender, wake) = (self.sender.clone(), std::sync::Arc::clone(&self.wake));
        threads.spawn(move || {
            let ended = std::panic::catch_unwind(std::panic::AssertUnwindSafe(job));
            // The receiver lives as long as the analysis that spawned the job.
            let _ = sender.send(ended);
            wake.notify_one();
        });
    }

    /// What the jobs done so far gave, without waiting.
    pub(crate) fn done(&self) -> Vec<T> {
        self.receiver.try_iter().map(resumed).collect()
    }

    /// What the next job to end gives and whatever else ended meanwhile, waiting
    /// for it on this thread (only when a job is in flight).
    pub(crate) fn wait(&self) -> Vec<T> {
        let first = self.receiver.recv().into_iter();
        first.chain(self.receiver.try_iter()).map(resumed).collect()
    }

    /// Notified when a job has ended since the last wake-up (an async wait; the
    /// ends are then taken with [`Self::done`]).
    pub(crate) fn woken(&self) -> std::sync::Arc<tokio::sync::Notify> {
        std::sync::Arc::clone(&self.wake)
    }
}

/// What a job gave, or its panic resumed on this thread.
fn resumed<T>(ended: std::thread::Result<T>) -> T {
    ended.unwrap_or_else(|panic| std::panic::resume_unwind(panic))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    /// One worker: no threads, the jobs run on the calling thread.
    #[test]
    fn one_worker_starts_no_thread() {
        assert!(Pool::new(1).threads().is_none());
        assert!(Pool::new(0).threads().is_none());
    }

    /// Every job spawned ends once, with what it gave, and the jobs run on the same
    /// persistent threads, never more than `workers` of them, not the caller's.
    #[test]
    fn every_job_ends_once_on_the_same_persistent_threads() {
        let pool = Pool::new(2);
        let threads = pool.threads().expect("two workers");
        let finished = Finished::new();
        let caller = std::thread::current().id();
        let mut ended = Vec::new();
        let mut seen = std::collections::HashSet::new();
        for batch in 0..10_u32 {
            for job in 0..8 {
                finished.spawn(threads, move || {
                    std::thread::sleep(Duration::from_millis(1));
                    (batch * 8 + job, std::thread::current().id())
                });
            }
            while ended.len() < ((batch + 1) * 8) as usize {
                for (job, thread) in finished.wait() {
                    ended.push(job);
                    seen.insert(thread);
                }
            }
        }
        assert!(finished.done().is_empty(), "no job ended twice");
        ended.sort_unstable();
        assert_eq!(ended, (0..80).collect::<Vec<_>>());
        assert!(!seen.contains(&caller), "a job ran on the calling thread");
        assert!(
            (1..=2).contains(&seen.len()),
            "{} threads: {seen:?}",
            seen.len()
        );
    }

    /// A slow job does not hold the others back: it waits until the fast jobs'
    /// ends were taken (were the ends taken only once all are done, it would wait
    /// for ever: it gives up after 10 s and the test fails).
    #[test]
    fn a_slow_job_does_not_delay_the_others_ends() {
        let pool = Pool::new(2);
        let threads = pool.threads().expect("two workers");
        let finished = Finished::new();
        let (fast_taken, wait_for_fast) = mpsc::sync_channel::<()>(1);
        finished.spawn(threads, move || {
            (
                "slow",
                wait_for_fast.recv_timeout(Duration::from_secs(10)).is_ok(),
            )
        });
        for job in ["fast 1", "fast 2"] {
            finished.spawn(threads, move || (job, true));
        }
        let mut order = Vec::new();
        while order.len() < 3 {
            for (job, in_time) in finished.wait() {
                assert!(in_time, "the slow job ended before the fast ones");
                order.push(job);
                if order.len() == 2 {
                    fast_taken.send(()).unwrap();
                }
            }
        }
        assert_eq!(order[2], "slow", "in the order they ended: {order:?}");
    }

    /// A job's panic is resumed where its end is taken, and the pool runs on.
    #[test]
    fn a_jobs_panic_is_resumed_where_its_end_is_taken() {
        let pool = Pool::new(2);
        let threads = pool.threads().expect("two workers");
        let finished = Finished::new();
        finished.spawn(threads, || -> u32 { panic!("a bite's analysis failed") });
        let taken = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| finished.wait()));
        let panic = taken.expect_err("the panic resumed");
        assert_eq!(
            panic.downcast_ref::<&str>(),
            Some(&"a bite's analysis failed")
        );
        finished.spawn(threads, || 5);
        assert_eq!(finished.wait(), vec![5]);
    }

    /// A job's end wakes an async waiter.
    #[test]
    fn an_end_wakes_the_async_waiter() {
        let pool = Pool::new(2);
        let threads = pool.threads().expect("two workers");
        let finished = Finished::new();
        let woken = finished.woken();
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_time()
            .build()
            .unwrap();
        finished.spawn(threads, || 7);
        let waited = runtime.block_on(async {
            tokio::time::timeout(Duration::from_secs(10), woken.notified()).await
        });
        assert!(waited.is_ok(), "not woken within 10 s");
        assert_eq!(finished.done(), vec![7]);
    }
}
