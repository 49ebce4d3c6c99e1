//! The analysis' bounded pool: a driveline's share of the messages that may take a
//! bite's analysis (and the tandem and rod mills' share) runs on one of `workers`
//! persistent threads, and says so when it is done ([`Finished`]); the analysis
//! task does not wait for it, but takes up the next messages meanwhile (a share for
//! a driveline still being analysed waits for it: `super::flight`). A slow job so
//! delays only its own driveline.
//!
//! The threads ([`Threads`]) are started once, at the first job, and kept, so a job
//! costs the wake-up of an idle thread rather than the start of a new one (some tens
//! of microseconds, more on a loaded machine, hundreds of times a second). An idle
//! thread sleeps on the queue's condition variable. They were rayon's, whose idle
//! threads spin (`sched_yield` in a loop) before they sleep: between the bursts of
//! bites at 128 drivelines that spinning took 28% of the analysis threads' CPU
//! (docs/measured.md), on a machine of two cores shared with the readers and the
//! writers; a queue under a mutex is all this pool needs. Nothing queues without
//! bound: each driveline and the mills have at most one job in flight, and the
//! finished jobs' channel at most one message per job.

use std::collections::VecDeque;
use std::sync::{mpsc, Arc, Condvar, Mutex, OnceLock};

/// A pool of `workers` analysis threads, started when first needed.
#[derive(Debug)]
pub(crate) struct Pool {
    workers: usize,
    /// The threads (`None`: they could not be started, every share runs inline).
    threads: OnceLock<Option<Threads>>,
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
    pub(crate) fn threads(&self) -> Option<&Threads> {
        if self.workers == 1 {
            return None;
        }
        self.threads
            .get_or_init(|| {
                Threads::start(self.workers)
                    .inspect_err(|error| {
                        tracing::error!(%error, workers = self.workers, "the analysis pool's threads did not start: the analysis runs on one thread")
                    })
                    .ok()
            })
            .as_ref()
    }
}

/// A job: run once on one of the threads. It must not panic ([`Finished::spawn`]
/// catches its jobs' panics): a panic would end its thread.
type Job = Box<dyn FnOnce() + Send>;

/// The pool's threads, named `analysis-N`, and their queue of jobs: taken in the
/// order they came. Dropping this lets the threads end once the queue is empty.
#[derive(Debug)]
pub(crate) struct Threads {
    shared: Arc<Shared>,
}

/// What the threads share.
struct Shared {
    queue: Mutex<Queue>,
    /// Notified when a job is queued or the threads are to end.
    ready: Condvar,
}

impl std::fmt::Debug for Shared {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let queue = crate::lock(&self.queue);
        f.debug_struct("Shared")
            .field("queued", &queue.jobs.len())
            .field("closed", &queue.closed)
            .finish()
    }
}

struct Queue {
    jobs: VecDeque<Job>,
    /// The pool was dropped: a thread ends when it finds the queue empty.
    closed: bool,
}

impl Threads {
    /// Start `workers` threads.
    fn start(workers: usize) -> std::io::Result<Self> {
        let threads = Self {
            shared: Arc::new(Shared {
                queue: Mutex::new(Queue {
                    jobs: VecDeque::new(),
                    closed: false,
                }),
                ready: Condvar::new(),
            }),
        };
        for index in 0..workers {
            let shared = Arc::clone(&threads.shared);
            // On an error the threads started so far end with `threads`' drop.
            std::thread::Builder::new()
                .name(format!("analysis-{index}"))
                .spawn(move || shared.work())?;
        }
        Ok(threads)
    }

    /// Queue `job`; an idle thread takes it at once.
    pub(crate) fn spawn(&self, job: impl FnOnce() + Send + 'static) {
        crate::lock(&self.shared.queue)
            .jobs
            .push_back(Box::new(job));
        self.shared.ready.notify_one();
    }
}

impl Drop for Threads {
    fn drop(&mut self) {
        crate::lock(&self.shared.queue).closed = true;
        self.shared.ready.notify_all();
    }
}

impl Shared {
    /// A thread's life: the queue's jobs one after another, asleep while it is empty,
    /// until the pool is dropped.
    fn work(&self) {
        loop {
            let job = {
                let mut queue = crate::lock(&self.queue);
                loop {
                    if let Some(job) = queue.jobs.pop_front() {
                        break job;
                    }
                    if queue.closed {
                        return;
                    }
                    queue = self
                        .ready
                        .wait(queue)
                        .unwrap_or_else(std::sync::PoisonError::into_inner);
                }
            };
            job();
        }
    }
}

/// Jobs' ends: each job in flight sends what it gives once done, and wakes the
/// analysis task waiting on [`Self::woken`]. A job that panics sends its panic, which
/// the analysis task resumes when it takes that end (as a job run on its own thread
/// would panic there).
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
    pub(crate) fn spawn(&self, threads: &Threads, job: impl FnOnce() -> T + Send + 'static) {
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

    /// Dropping the pool ends its threads (they hold what they share: once it is
    /// gone, every thread has ended).
    #[test]
    fn the_threads_end_with_the_pool() {
        let pool = Pool::new(2);
        let threads = pool.threads().expect("two workers");
        let finished = Finished::new();
        finished.spawn(threads, || 1);
        assert_eq!(finished.wait(), vec![1]);
        let shared = Arc::downgrade(&threads.shared);
        drop(pool);
        let dropped = std::time::Instant::now();
        while shared.upgrade().is_some() {
            assert!(
                dropped.elapsed() < Duration::from_secs(10),
                "the threads still run 10 s after the pool was dropped"
            );
            std::thread::sleep(Duration::from_millis(1));
        }
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
