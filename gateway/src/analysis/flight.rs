//! The drivelines' shares in flight: the analysis takes messages up as they come and
//! starts each driveline's share of them at once, on the pool when it may complete a
//! bite window, on the analysis task otherwise (taking a block in is a few
//! microseconds), without waiting for the shares already running. A driveline whose
//! previous share still runs keeps the new one until it ends, so its steps stay in
//! order; the mills' share likewise. When shares end, the bites they completed are
//! published together (one change of the results, one history commit, one PLC
//! write), and the shares that waited for them start.
//!
//! Before the analysis task touches an analyser for anything else (a command, a
//! reload's thresholds or drivelines, gap maps), it waits until every share in
//! flight has ended ([`Flight::settle`]): a command given after a block is in
//! effect after that block's steps, as when the messages were taken up one at a time.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use tokio::sync::broadcast;

use super::chatter::ChatterAnalysis;
use super::driveline::{publish_bites, BiteReport, DrivelineAnalyzer};
use super::pool::{Finished, Pool};
use super::rod_monitor::RodAnalysis;
use super::shares::Step;
use crate::field::acquired::Acquired;
use crate::state::board::Board;

/// Most reader messages (blocks, gaps, process values) the analysis takes up
/// together: what is ready when it turns to them, up to this many (the readers'
/// channel holds more; the rest are taken up next). Also the most steps that wait
/// for their drivelines' shares in flight before the analysis takes up more.
pub const MAX_ROUND_MESSAGES: usize = 1024;

/// The tandem mills' and the rod mills' monitors: each mill's state depends only on
/// its own messages' order, so they take every message in order, as one share beside
/// the drivelines'.
#[derive(Debug)]
pub(super) struct Mills {
    pub(super) chatter: ChatterAnalysis,
    pub(super) rod_mills: RodAnalysis,
}

impl Mills {
    /// Take `message`.
    fn handle(&mut self, message: &Acquired) {
        // A block arrived when its reader handed it over, not when the analysis (or
        // the mills' share) took it up.
        let arrival = match message {
            Acquired::Samples { handed, .. } => *handed,
            _ => Instant::now(),
        };
        self.chatter.handle_at(message, arrival);
        self.rod_mills.handle(message);
    }
}

/// A bite waiting for its driveline's extra channels.
#[derive(Debug)]
struct HeldBite {
    /// The bite, analysed.
    report: BiteReport,
    /// When it is released whatever the extra channels hold.
    deadline: Instant,
}

/// What a share in flight gives when it ends.
#[derive(Debug)]
pub(super) enum Ended {
    /// Driveline `.0`'s share: the bites it completed, analysed.
    Driveline(usize, Vec<BiteReport>),
    /// The mills' share.
    Mills,
}

/// The drivelines' analysers and the mills' monitors, their shares in flight and
/// those waiting for them.
#[derive(Debug)]
pub(super) struct Flight {
    /// The drivelines' analysers, each locked by the job that runs its share (on
    /// the pool) while it runs; the analysis task touches one only when it has no
    /// share in flight, or waits for them all to end first ([`Self::settle`]).
    pub(super) drivelines: Vec<Arc<Mutex<DrivelineAnalyzer>>>,
    /// Per driveline: how long a bite waits for its extra channels.
    extra_hold: Vec<Duration>,
    /// Bites waiting for their extra channels, in the order they completed.
    held: Vec<HeldBite>,
    /// The tandem mills' chatter monitors and the rod mills' span stability
    /// monitors (locked by their share, as a driveline's analyser).
    mills: Arc<Mutex<Mills>>,
    /// The threads that analyse the shares (`analysis.workers`, resolved: at least
    /// 1), started once and kept.
    pool: Pool,
    board: Arc<Board>,
    bites: broadcast::Sender<BiteReport>,
    /// Per driveline: whether a share of its runs on the pool.
    busy: Vec<bool>,
    /// Per driveline: the steps taken up while its share ran, to run next.
    waiting: Vec<Vec<Step>>,
    /// Whether the mills' share runs on the pool (`None`: no mills to analyse).
    mills_busy: Option<bool>,
    /// The messages taken up while the mills' share ran, to run next.
    mills_waiting: Vec<Arc<Acquired>>,
    /// Shares in flight.
    in_flight: usize,
    ended: Finished<Ended>,
}

impl Flight {
    /// No drivelines yet, and `mills` (their share is left out when they have no
    /// monitors), run on `pool`, their results on `board` and each bite sent to
    /// `bites`' subscribers.
    pub(super) fn new(
        pool: Pool,
        board: Arc<Board>,
        bites: broadcast::Sender<BiteReport>,
        mills: Mills,
    ) -> Self {
        let no_mills = mills.chatter.monitors().is_empty() && mills.rod_mills.monitors().is_empty();
        Self {
            drivelines: Vec::new(),
            extra_hold: Vec::new(),
            held: Vec::new(),
            mills: Arc::new(Mutex::new(mills)),
            pool,
            board,
            bites,
            busy: Vec::new(),
            waiting: Vec::new(),
            mills_busy: (!no_mills).then_some(false),
            mills_waiting: Vec::new(),
            in_flight: 0,
            ended: Finished::new(),
        }
    }

    /// One more driveline, after the others: `analyzer`, its bites held `hold` for
    /// its extra channels.
    pub(super) fn add_driveline(&mut self, analyzer: DrivelineAnalyzer, hold: Duration) {
        self.drivelines.push(Arc::new(Mutex::new(analyzer)));
        self.extra_hold.push(hold);
        self.busy.push(false);
        self.waiting.push(Vec::new());
    }

    /// Driveline `index`'s analyser (`None`: no such driveline); waits for its
    /// share in flight, if any, to end (wait for all of them first to see it after
    /// the messages taken up: [`Self::settle`]).
    pub(super) fn driveline(&self, index: usize) -> Option<MutexGuard<'_, DrivelineAnalyzer>> {
        self.drivelines
            .get(index)
            .map(|driveline| crate::lock(driveline))
    }

    /// The mills' monitors (wait for the shares in flight first to see them after
    /// the messages taken up: [`Self::settle`]).
    pub(super) fn mills(&self) -> MutexGuard<'_, Mills> {
        crate::lock(&self.mills)
    }

    /// Whether a share is in flight.
    pub(super) fn any(&self) -> bool {
        self.in_flight > 0
    }

    /// Notified when a share has ended (take the ends with [`Self::finished`]).
    pub(super) fn woken(&self) -> Arc<tokio::sync::Notify> {
        self.ended.woken()
    }

    /// Take `messages` up, in their order, with each driveline's share of them
    /// (`shares`, in order): each starts now (or after its share in flight), and so
    /// does the mills' (every message). Does not wait for the shares on the pool;
    /// returns the bites released meanwhile (published and recorded): those of the
    /// shares that ran on this thread and of those that ended on the pool. When more
    /// steps than [`MAX_ROUND_MESSAGES`] wait for their drivelines (or more messages
    /// for the mills), waits for shares to end until they do not: the readers'
    /// channel then fills, as the analysis falls behind, and nothing queues here
    /// without bound.
    pub(super) fn take_up(
        &mut self,
        messages: Vec<Arc<Acquired>>,
        shares: Vec<Vec<Step>>,
    ) -> Vec<BiteReport> {
        let mut released = Vec::new();
        if self.mills_busy.is_some() {
            self.mills_waiting.extend(messages);
            self.start_mills();
        }
        // The shares that may complete a window first, so the pool starts on them
        // while the others run here.
        let mut light = Vec::new();
        for (driveline, steps) in shares.into_iter().enumerate() {
            if steps.is_empty() {
                continue;
            }
            if self.busy[driveline] {
                self.waiting[driveline].extend(steps);
            } else if crate::lock(&self.drivelines[driveline]).may_complete_a_window(&steps) {
                released.extend(self.start(driveline, steps));
            } else {
                light.push((driveline, steps));
            }
        }
        for (driveline, steps) in light {
            let reports = crate::lock(&self.drivelines[driveline]).run_steps(&steps, &self.board);
            // Bites only when a gap or a block completed a window after all.
            released.extend(self.publish(reports));
            let ended = self.ended.done();
            released.extend(self.ends(ended));
        }
        while self.waiting.iter().map(Vec::len).sum::<usize>() > MAX_ROUND_MESSAGES
            || self.mills_waiting.len() > MAX_ROUND_MESSAGES
        {
            let ended = self.ended.wait();
            released.extend(self.ends(ended));
        }
        // The messages may have brought held bites their extra samples.
        released.extend(self.release_held(Instant::now(), false));
        released
    }

    /// Start driveline `driveline`'s share `steps`: on the pool when it has
    /// threads, else here (its bites published at once, and returned).
    fn start(&mut self, driveline: usize, steps: Vec<Step>) -> Vec<BiteReport> {
        let analyzer = Arc::clone(&self.drivelines[driveline]);
        let Some(threads) = self.pool.threads() else {
            let reports = crate::lock(&analyzer).run_steps(&steps, &self.board);
            return self.publish(reports);
        };
        let board = Arc::clone(&self.board);
        self.busy[driveline] = true;
        self.in_flight += 1;
        self.ended.spawn(threads, move || {
            let reports = crate::lock(&analyzer).run_steps(&steps, &board);
            Ended::Driveline(driveline, reports)
        });
        Vec::new()
    }

    /// Start the mills' share of the messages waiting for it, unless one runs.
    fn start_mills(&mut self) {
        if self.mills_busy != Some(false) || self.mills_waiting.is_empty() {
            return;
        }
        let messages = std::mem::take(&mut self.mills_waiting);
        let mills = Arc::clone(&self.mills);
        let share = move || {
            let mut mills = crate::lock(&mills);
            for message in &messages {
                mills.handle(message);
            }
        };
        match self.pool.threads() {
            Some(threads) => {
                self.mills_busy = Some(true);
                self.in_flight += 1;
                self.ended.spawn(threads, move || {
                    share();
                    Ended::Mills
                });
            }
            None => share(),
        }
    }

    /// Take the shares that ended (each driveline's in the order it ran): their
    /// bites are published together, and the shares that waited for them start.
    /// Returns the bites released (published and recorded).
    pub(super) fn finished(&mut self) -> Vec<BiteReport> {
        let ended = self.ended.done();
        self.ends(ended)
    }

    /// As [`Self::finished`], for the shares `ended`.
    fn ends(&mut self, ended: Vec<Ended>) -> Vec<BiteReport> {
        if ended.is_empty() {
            return Vec::new();
        }
        let mut reports = Vec::new();
        let mut next = Vec::new();
        for end in ended {
            self.in_flight -= 1;
            match end {
                Ended::Driveline(driveline, bites) => {
                    self.busy[driveline] = false;
                    reports.extend(bites);
                    next.push(driveline);
                }
                Ended::Mills => self.mills_busy = Some(false),
            }
        }
        let mut released = self.publish(reports);
        for driveline in next {
            let steps = std::mem::take(&mut self.waiting[driveline]);
            if !steps.is_empty() {
                released.extend(self.start(driveline, steps));
            }
        }
        self.start_mills();
        released.extend(self.release_held(Instant::now(), false));
        released
    }

    /// Wait until no share is in flight (and none waits); returns the bites released
    /// meanwhile.
    pub(super) fn settle(&mut self) -> Vec<BiteReport> {
        let mut released = Vec::new();
        while self.any() {
            let ended = self.ended.wait();
            released.extend(self.ends(ended));
        }
        released
    }

    /// Publish the bites `reports` of drivelines with no share in flight, those
    /// with extra channels held for them ([`Self::release_held`]); returns those
    /// published.
    fn publish(&mut self, reports: Vec<BiteReport>) -> Vec<BiteReport> {
        if reports.is_empty() {
            return reports;
        }
        // The hold counts from now, not from the block's hand-over: a bite found late
        // (the analysis behind) still waits its whole hold for the extra channels'
        // blocks, which are behind it in the readers' channel.
        let now = Instant::now();
        let (ready, held): (Vec<_>, Vec<_>) = reports
            .into_iter()
            .partition(|report| self.extra_hold[report.driveline].is_zero());
        self.held.extend(held.into_iter().map(|report| HeldBite {
            deadline: now + self.extra_hold[report.driveline],
            report,
        }));
        self.publish_now(&ready);
        ready
    }

    /// Publish `reports` together (one change of the results, one history commit,
    /// one PLC write); their drivelines have no share in flight.
    fn publish_now(&self, reports: &[BiteReport]) {
        // Each driveline locked once, however many of its bites.
        let mut locked = BTreeMap::new();
        for report in reports {
            let driveline = report.driveline;
            locked
                .entry(driveline)
                .or_insert_with(|| crate::lock(&self.drivelines[driveline]));
        }
        let bites: Vec<_> = reports
            .iter()
            .map(|report| (&*locked[&report.driveline], report))
            .collect();
        publish_bites(&self.board, &self.bites, &bites);
    }

    /// Release the held bites (in the order they completed, per driveline) whose
    /// extra channels reach the end of their window, whose bound has passed at `now`,
    /// or all when `all`: their captures take what the rings hold, and they are
    /// published and recorded together. A bite of a driveline with a share in flight
    /// waits for it to end (the share may bring the extra samples). Returns them.
    pub(super) fn release_held(&mut self, now: Instant, all: bool) -> Vec<BiteReport> {
        if all {
            self.settle();
        }
        let mut released = Vec::new();
        let mut waiting: Vec<usize> = Vec::new();
        for mut held in std::mem::take(&mut self.held) {
            let index = held.report.driveline;
            let ready = !self.busy[index] && !waiting.contains(&index) && {
                let driveline = crate::lock(&self.drivelines[index]);
                let ready =
                    all || now >= held.deadline || driveline.extras_reach_window_end(&held.report);
                if ready {
                    driveline.capture_extras(&mut held.report);
                }
                ready
            };
            if ready {
                released.push(held.report);
            } else {
                waiting.push(index);
                self.held.push(held);
            }
        }
        self.publish_now(&released);
        released
    }
}
