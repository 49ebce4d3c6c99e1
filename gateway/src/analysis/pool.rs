//! The analysis round's bounded pool: the jobs of one round (a driveline's share of
//! the blocks drained together) that may take a bite's analysis run on a pool of
//! `workers` persistent threads, the others on the round's own thread, and each
//! job's result is handed to the publisher as soon as it is done, together with
//! whatever else finished meanwhile. A slow job delays only itself: the others'
//! results are published while it runs; the round (and so the next blocks) ends when
//! it ends.
//!
//! The threads are rayon's (`ThreadPool::in_place_scope`): started once, at the
//! first round that has work for more than one, and kept, so a round costs a wake-up
//! of idle threads rather than the start of new ones (scoped threads spawned per
//! round, as before, cost some tens of microseconds each, more on a loaded machine,
//! at every round: a round per DAQ poll, hundreds a second). The scope lets the jobs
//! borrow the drivelines' analysers without moving them in and out of
//! `Arc<Mutex<_>>`, and the publisher runs on the calling thread inside it, so the
//! results are published as they come rather than once all are done (what rayon's
//! `par_iter` would give). Nothing queues without bound: the jobs are the round's (at
//! most [`super::MAX_ROUND_MESSAGES`] blocks' worth) and the results' channel holds
//! one result per job.

use std::sync::mpsc;
use std::sync::OnceLock;

/// A pool of `workers` analysis threads, started when first needed.
#[derive(Debug)]
pub(crate) struct Pool {
    workers: usize,
    /// The threads (`None`: they could not be started, the rounds run inline).
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

    /// The threads, started at the first call.
    fn threads(&self) -> Option<&rayon::ThreadPool> {
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

    /// Run `jobs` through `work`, calling `publish` on the calling thread with each
    /// group of results that are done, in the order they finished; returns once every
    /// job is done and published. The `heavy` jobs (those that may take a bite's
    /// analysis) run on the pool when there are two or more and more than one worker;
    /// the others run on the calling thread meanwhile (taking a block's samples in is
    /// a few microseconds: waking a pool thread for it costs more than it saves, and a
    /// woken thread that finds no work spins on `sched_yield` before it sleeps, which
    /// on a small machine takes a core from the readers and the outputs). Otherwise
    /// every job runs on the calling thread, the heavy ones first.
    pub(crate) fn run_round<J: Send, R: Send>(
        &self,
        jobs: Vec<J>,
        heavy: impl Fn(&J) -> bool,
        work: impl Fn(J) -> R + Sync,
        mut publish: impl FnMut(Vec<R>),
    ) {
        let (pooled, inline): (Vec<J>, Vec<J>) = jobs.into_iter().partition(|job| heavy(job));
        let threads = if self.workers > 1 && pooled.len() > 1 {
            self.threads()
        } else {
            None
        };
        let Some(threads) = threads else {
            for job in pooled.into_iter().chain(inline) {
                publish(vec![work(job)]);
            }
            return;
        };
        let (done, finished) = mpsc::sync_channel(pooled.len());
        threads.in_place_scope(|scope| {
            for job in pooled {
                let (done, work) = (done.clone(), &work);
                // Room for every job's result: never blocks. A publisher gone (it
                // panicked) ends the scope with its panic anyway.
                scope.spawn(move |_| {
                    let _ = done.send(work(job));
                });
            }
            drop(done);
            for job in inline {
                let mut group = vec![work(job)];
                group.extend(finished.try_iter());
                publish(group);
            }
            while let Ok(first) = finished.recv() {
                let mut group = vec![first];
                group.extend(finished.try_iter());
                publish(group);
            }
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Mutex;
    use std::time::Duration;

    /// Every job runs once and is published once, at any worker count, round after
    /// round on the same threads.
    #[test]
    fn every_job_is_published_once() {
        for workers in [1, 2, 3, 8] {
            let pool = Pool::new(workers);
            for _round in 0..3 {
                let mut published = Vec::new();
                pool.run_round(
                    (0..20).collect(),
                    |job| job % 3 != 0,
                    |job: u32| job * 10,
                    |group| published.extend(group),
                );
                published.sort_unstable();
                assert_eq!(published, (0..20).map(|j| j * 10).collect::<Vec<_>>());
            }
        }
    }

    /// The rounds run on the pool's threads, the same ones every round (persistent),
    /// never more than `workers` of them, and not on the calling thread.
    #[test]
    fn the_rounds_run_on_the_same_persistent_threads() {
        let pool = Pool::new(2);
        let caller = std::thread::current().id();
        let mut seen = std::collections::HashSet::new();
        for _round in 0..20 {
            pool.run_round(
                (0..8).collect(),
                |_| true,
                |_job: u32| {
                    std::thread::sleep(Duration::from_millis(1));
                    std::thread::current().id()
                },
                |group| seen.extend(group),
            );
        }
        assert!(!seen.contains(&caller), "a job ran on the calling thread");
        assert!(
            (1..=2).contains(&seen.len()),
            "{} threads over 20 rounds: {seen:?}",
            seen.len()
        );
    }

    /// The light jobs run on the calling thread beside the heavy ones on the pool; a
    /// round with fewer than two heavy jobs wakes no pool thread at all.
    #[test]
    fn light_jobs_run_on_the_calling_thread() {
        let pool = Pool::new(2);
        let caller = std::thread::current().id();
        let on = |heavy_jobs: u32| {
            let mut ran = Vec::new();
            pool.run_round(
                (0..10).collect(),
                |&job| job < heavy_jobs,
                |job: u32| (job, std::thread::current().id()),
                |group| ran.extend(group),
            );
            ran.sort_unstable_by_key(|&(job, _)| job);
            assert_eq!(ran.len(), 10);
            ran
        };
        for (job, thread) in on(3) {
            assert_eq!(thread == caller, job >= 3, "job {job}");
        }
        assert!(on(1).iter().all(|&(_, thread)| thread == caller));
        assert!(on(0).iter().all(|&(_, thread)| thread == caller));
    }

    /// A slow job does not hold the others back: it waits until the fast jobs'
    /// results were published (if the pool published only at the round's end, the
    /// slow job would wait for ever: it gives up after 10 s and the test fails).
    #[test]
    fn a_slow_job_does_not_delay_the_others_publication() {
        let (fast_published, wait_for_fast) = mpsc::sync_channel::<()>(1);
        let wait_for_fast = Mutex::new(wait_for_fast);
        let mut order = Vec::new();
        Pool::new(2).run_round(
            vec!["slow", "fast 1", "fast 2"],
            |_| true,
            |job| {
                if job == "slow" {
                    let waited = crate::lock(&wait_for_fast).recv_timeout(Duration::from_secs(10));
                    (job, waited.is_ok())
                } else {
                    (job, true)
                }
            },
            |group| {
                for (job, in_time) in group {
                    order.push(job);
                    assert!(in_time, "the slow job was published before the fast ones");
                    if order.len() == 2 {
                        fast_published.send(()).unwrap();
                    }
                }
            },
        );
        assert_eq!(order.len(), 3);
        assert_eq!(
            order[2], "slow",
            "published in the order they finished: {order:?}"
        );
    }
}
