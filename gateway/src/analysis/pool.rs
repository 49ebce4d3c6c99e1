//! The analysis round's bounded pool: the jobs of one round (a driveline's share of
//! the blocks drained together) run on at most `workers` threads, and each job's
//! result is handed to the publisher as soon as it is done, together with whatever
//! else finished meanwhile. A slow job delays only itself: the others' results are
//! published while it runs; the round (and so the next blocks) ends when it ends.
//!
//! Scoped threads (`std::thread::scope`) rather than a crate's pool (rayon is not in
//! the workspace, and its `par_iter` would return the results only once all are
//! done): the jobs borrow the drivelines' analysers, which a scope allows without
//! moving them in and out of `Arc<Mutex<_>>`. Spawning the threads costs some tens
//! of microseconds per round against about 0.5 ms per bite analysed. Nothing queues
//! without bound: the jobs are the round's (at most [`super::MAX_ROUND_MESSAGES`]
//! blocks' worth) and the results' channel holds one result per job.

use std::sync::mpsc;
use std::sync::Mutex;

/// Run `jobs` through `work` on at most `workers` threads (inline on the calling
/// thread with one worker or one job), calling `publish` on the calling thread with
/// each group of results that are done, in the order they finished. Returns once
/// every job is done and published.
pub(crate) fn run_round<J: Send, R: Send>(
    jobs: Vec<J>,
    workers: usize,
    work: impl Fn(J) -> R + Sync,
    mut publish: impl FnMut(Vec<R>),
) {
    let threads = workers.min(jobs.len());
    if threads <= 1 {
        for job in jobs {
            publish(vec![work(job)]);
        }
        return;
    }
    let (done, finished) = mpsc::sync_channel(jobs.len());
    let queue = Mutex::new(jobs.into_iter());
    std::thread::scope(|scope| {
        for _ in 0..threads {
            let done = done.clone();
            let (queue, work) = (&queue, &work);
            scope.spawn(move || loop {
                let Some(job) = crate::lock(queue).next() else {
                    break;
                };
                // Room for every job's result: never blocks. A publisher gone (it
                // panicked) ends the scope with its panic anyway.
                if done.send(work(job)).is_err() {
                    break;
                }
            });
        }
        drop(done);
        while let Ok(first) = finished.recv() {
            let mut group = vec![first];
            group.extend(finished.try_iter());
            publish(group);
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    /// Every job runs once and is published once, at any worker count.
    #[test]
    fn every_job_is_published_once() {
        for workers in [1, 2, 3, 8] {
            let mut published = Vec::new();
            run_round(
                (0..20).collect(),
                workers,
                |job: u32| job * 10,
                |group| published.extend(group),
            );
            published.sort_unstable();
            assert_eq!(published, (0..20).map(|j| j * 10).collect::<Vec<_>>());
        }
    }

    /// A slow job does not hold the others back: it waits until the fast jobs'
    /// results were published (if the pool published only at the round's end, the
    /// slow job would wait for ever: it gives up after 10 s and the test fails).
    #[test]
    fn a_slow_job_does_not_delay_the_others_publication() {
        let (fast_published, wait_for_fast) = mpsc::sync_channel::<()>(1);
        let wait_for_fast = Mutex::new(wait_for_fast);
        let mut order = Vec::new();
        run_round(
            vec!["slow", "fast 1", "fast 2"],
            2,
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
