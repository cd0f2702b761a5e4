//! The brick loaders (issue 39): a pool of threads that read bricks ahead of the GPU, in the
//! order the frames ask for them, into a bounded queue of bricks ready to upload.
//!
//! The schedule follows the ray-guided systems (Crassin et al. 2009; Hadwiger et al. 2012; Fogal
//! et al. 2013) and neuroglancer's chunk manager: what the last frame's rays asked for is the
//! whole request, so a new request replaces the queue (a brick no longer asked for is never
//! read), each request carries a priority (the caller's: coarse levels first, then front to
//! back), and the loaders stop reading when the ready queue holds its bound of bytes until the
//! caller takes some. Bricks that are ready and no longer asked for are dropped. The loaders
//! also keep the timeline of when any of them was reading, so that a frame can say how much of
//! its time the host and the GPU were busy at once.

use crate::bricks::{BrickLevels, BrickVoxels};
use std::collections::{BTreeSet, HashMap, HashSet};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};
use vellum_error::Result;

/// A brick read by a loader: its page-table entry and its voxels, or the sentence of why it
/// could not be read (naming the chunk).
pub struct Loaded {
    /// The brick's page-table entry.
    pub entry: usize,
    /// Its voxels, or why they could not be read.
    pub voxels: Result<BrickVoxels>,
}

/// Intervals (seconds since the loader started) during which at least one loader was reading.
pub type Timeline = Vec<(f64, f64)>;

/// What the loaders did since they started.
#[derive(Clone, Debug, Default)]
pub struct LoaderStats {
    /// Bricks read (failed ones included) and the bytes that travel for them.
    pub bricks: u64,
    /// Bytes that travel for them.
    pub bytes: u64,
    /// Bricks read and then dropped, no longer asked for when they were ready.
    pub(crate) dropped: u64,
    /// Seconds of reading, summed over the loaders.
    pub(crate) busy_s: f64,
}

struct State {
    /// Asked for and not yet taken by a loader: (priority, entry), smallest priority first.
    queue: BTreeSet<(u64, usize)>,
    priority: HashMap<usize, u64>,
    /// Everything asked for by the last request and the additions since: a brick read and no
    /// longer among them is dropped.
    asked: HashSet<usize>,
    in_flight: HashSet<usize>,
    ready: Vec<Loaded>,
    ready_bytes: u64,
    stop: bool,
    /// Loaders reading now, and since when the first of them started.
    reading: usize,
    since: f64,
    timeline: Timeline,
    stats: LoaderStats,
}

struct Shared {
    levels: Arc<BrickLevels>,
    state: Mutex<State>,
    /// Loaders wait here for requests or for room in the ready queue.
    work: Condvar,
    /// The caller waits here for arrivals.
    arrived: Condvar,
    ready_limit: u64,
    epoch: Instant,
}

/// Intervals kept in the timeline at most (later ones are merged into the last).
const TIMELINE_CAP: usize = 1 << 16;

/// A pool of loader threads on one pyramid; dropping it stops them.
pub struct BrickLoader {
    shared: Arc<Shared>,
    threads: Vec<std::thread::JoinHandle<()>>,
}

impl BrickLoader {
    /// `threads` loaders (at least one) reading bricks of `levels`, holding at most about
    /// `ready_bytes` of bricks ready to upload.
    pub fn new(levels: Arc<BrickLevels>, threads: usize, ready_bytes: u64) -> Self {
        let shared = Arc::new(Shared {
            levels,
            state: Mutex::new(State {
                queue: BTreeSet::new(),
                priority: HashMap::new(),
                asked: HashSet::new(),
                in_flight: HashSet::new(),
                ready: Vec::new(),
                ready_bytes: 0,
                stop: false,
                reading: 0,
                since: 0.0,
                timeline: Vec::new(),
                stats: LoaderStats::default(),
            }),
            work: Condvar::new(),
            arrived: Condvar::new(),
            ready_limit: ready_bytes.max(1),
            epoch: Instant::now(),
        });
        let threads = (0..threads.max(1))
            .map(|i| {
                let s = shared.clone();
                std::thread::Builder::new()
                    .name(format!("brick loader {i}"))
                    .spawn(move || s.run())
            })
            .filter_map(|t| t.ok())
            .collect();
        BrickLoader { shared, threads }
    }

    /// Loader threads for this machine: one per core, or `VELLUM_LOADERS` (for measuring).
    pub fn default_threads() -> usize {
        std::env::var("VELLUM_LOADERS")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(|| std::thread::available_parallelism().map_or(2, |n| n.get()))
    }

    /// The pyramid the loaders read.
    pub fn levels(&self) -> &Arc<BrickLevels> {
        &self.shared.levels
    }

    /// Asks for `wanted` (entry, priority; smaller first), replacing what was asked before:
    /// queued bricks no longer asked for are not read, and ready ones are dropped. Bricks being
    /// read or ready are not asked again.
    pub fn request(&self, wanted: &[(usize, u64)]) {
        let mut st = self.shared.lock();
        let asked: HashMap<usize, u64> = wanted.iter().copied().collect();
        let before = st.ready.len();
        st.ready.retain(|l| asked.contains_key(&l.entry));
        let dropped = (before - st.ready.len()) as u64;
        st.stats.dropped += dropped;
        st.ready_bytes = st.ready.iter().map(ready_bytes).sum();
        let ready: HashSet<usize> = st.ready.iter().map(|l| l.entry).collect();
        st.queue.clear();
        st.priority.clear();
        st.asked = asked.keys().copied().collect();
        for (&e, &p) in &asked {
            if !st.in_flight.contains(&e) && !ready.contains(&e) {
                st.queue.insert((p, e));
                st.priority.insert(e, p);
            }
        }
        drop(st);
        self.shared.work.notify_all();
    }

    /// Adds `wanted` to what is asked for (a brick asked again keeps the smaller priority).
    pub fn add(&self, wanted: &[(usize, u64)]) {
        let mut st = self.shared.lock();
        let ready: HashSet<usize> = st.ready.iter().map(|l| l.entry).collect();
        for &(e, p) in wanted {
            st.asked.insert(e);
            if st.in_flight.contains(&e) || ready.contains(&e) {
                continue;
            }
            match st.priority.get(&e).copied() {
                Some(old) if old <= p => {}
                Some(old) => {
                    st.queue.remove(&(old, e));
                    st.queue.insert((p, e));
                    st.priority.insert(e, p);
                }
                None => {
                    st.queue.insert((p, e));
                    st.priority.insert(e, p);
                }
            }
        }
        drop(st);
        self.shared.work.notify_all();
    }

    /// The bricks ready now, without waiting: at most `max` that upload, and with them the ready
    /// bricks `free` says upload nothing (of one value, sharing a slot already made),
    /// [`FREE_PER_UPLOAD`] for each that uploads at most.
    pub fn take(&self, max: usize, free: &dyn Fn(&BrickVoxels) -> bool) -> Vec<Loaded> {
        let mut st = self.shared.lock();
        self.take_locked(&mut st, max, Some(free))
    }

    /// The bricks ready, at most `max`, waiting until at least `min` are (or everything asked
    /// for is, or the ready queue is at its bound of bytes, or `timeout` has passed).
    pub fn take_at_least(&self, min: usize, max: usize, timeout: Duration) -> Vec<Loaded> {
        let until = Instant::now() + timeout;
        let mut st = self.shared.lock();
        loop {
            let outstanding = st.queue.len() + st.in_flight.len();
            // A full ready queue stops the loaders: waiting for more would wait for nothing.
            let full = st.ready_bytes >= self.shared.ready_limit;
            if st.ready.len() >= min.max(1) || outstanding == 0 || full {
                break;
            }
            let now = Instant::now();
            if now >= until {
                break;
            }
            st = self
                .shared
                .arrived
                .wait_timeout(st, until - now)
                .map(|(g, _)| g)
                .unwrap_or_else(|p| p.into_inner().0);
        }
        self.take_locked(&mut st, max, None)
    }

    /// The ready bricks in order, up to the `max`-th that uploads; bricks `free` says upload
    /// nothing do not count, [`FREE_PER_UPLOAD`] of them for each that does at most.
    fn take_locked(
        &self,
        st: &mut MutexGuard<State>,
        max: usize,
        free: Option<&dyn Fn(&BrickVoxels) -> bool>,
    ) -> Vec<Loaded> {
        let all = max.saturating_mul(if free.is_some() {
            FREE_PER_UPLOAD + 1
        } else {
            1
        });
        let (mut uploads, mut n) = (0, 0);
        for l in st.ready.iter().take(all) {
            if uploads == max {
                break;
            }
            n += 1;
            let costs_nothing = free.is_some_and(|f| l.voxels.as_ref().is_ok_and(f));
            uploads += usize::from(!costs_nothing);
        }
        let got: Vec<Loaded> = st.ready.drain(..n).collect();
        st.ready_bytes = st.ready.iter().map(ready_bytes).sum();
        if n > 0 {
            self.shared.work.notify_all();
        }
        got
    }

    /// Bricks ready to be taken.
    #[cfg(test)]
    fn stats_ready(&self) -> usize {
        self.shared.lock().ready.len()
    }

    /// Bricks asked for and not yet taken: queued, being read or ready.
    pub fn outstanding(&self) -> usize {
        let st = self.shared.lock();
        st.queue.len() + st.in_flight.len() + st.ready.len()
    }

    /// What the loaders did so far.
    pub fn stats(&self) -> LoaderStats {
        self.shared.lock().stats.clone()
    }

    /// When any loader was reading, in seconds since `at` (an interval still open ends now).
    pub fn timeline(&self, at: Instant) -> Timeline {
        let st = self.shared.lock();
        let shift = at
            .saturating_duration_since(self.shared.epoch)
            .as_secs_f64()
            - self
                .shared
                .epoch
                .saturating_duration_since(at)
                .as_secs_f64();
        let mut t: Timeline = st
            .timeline
            .iter()
            .map(|&(a, b)| (a - shift, b - shift))
            .collect();
        if st.reading > 0 {
            t.push((st.since - shift, self.shared.now() - shift));
        }
        t
    }
}

/// How long dropping a loader waits for its threads to finish the reads they are in.
const JOIN_WAIT: Duration = Duration::from_millis(250);

impl Drop for BrickLoader {
    /// Stops the loaders and joins them. A loader still inside a read after [`JOIN_WAIT`] (a
    /// server that stalls, tried again after a time-out) is left to end on its own: it holds only
    /// its share of the queue, and stops after that read. So closing a view of a stalled server
    /// does not wait for its time-outs.
    fn drop(&mut self) {
        self.shared.lock().stop = true;
        self.shared.work.notify_all();
        let deadline = Instant::now() + JOIN_WAIT;
        for t in self.threads.drain(..) {
            while !t.is_finished() && Instant::now() < deadline {
                std::thread::sleep(Duration::from_millis(2));
            }
            if t.is_finished() {
                let _ = t.join();
            }
        }
    }
}

/// Bricks that upload nothing [`Loader::take`] hands out at most for each brick it counts: a view
/// that turns into empty space takes its bricks of one value at once (on lavapipe a frame took
/// 24 bricks, most of them of one value, while its rays sampled coarser levels around the rest).
pub const FREE_PER_UPLOAD: usize = 7;

fn ready_bytes(l: &Loaded) -> u64 {
    l.voxels.as_ref().map_or(0, BrickVoxels::travel_bytes)
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    fn now(&self) -> f64 {
        self.epoch.elapsed().as_secs_f64()
    }

    /// A loader: takes the most urgent brick while the ready queue has room, reads it, queues it.
    fn run(&self) {
        let mut st = self.lock();
        loop {
            if st.stop {
                return;
            }
            let room = st.ready_bytes < self.ready_limit;
            let Some(&(p, entry)) = st.queue.first().filter(|_| room) else {
                st = self.work.wait(st).unwrap_or_else(|p| p.into_inner());
                continue;
            };
            st.queue.remove(&(p, entry));
            st.priority.remove(&entry);
            st.in_flight.insert(entry);
            if st.reading == 0 {
                st.since = self.now();
            }
            st.reading += 1;
            drop(st);
            let start = Instant::now();
            let voxels = match self.levels.key(entry) {
                Some(k) => self.levels.voxels(k),
                None => Err(vellum_error::Error::Invalid(format!(
                    "page-table entry {entry} names no brick"
                ))),
            };
            let busy = start.elapsed().as_secs_f64();
            st = self.lock();
            st.reading -= 1;
            if st.reading == 0 {
                let (since, now) = (st.since, self.now());
                push_interval(&mut st.timeline, (since, now));
            }
            st.in_flight.remove(&entry);
            st.stats.bricks += 1;
            st.stats.busy_s += busy;
            let loaded = Loaded { entry, voxels };
            let bytes = ready_bytes(&loaded);
            st.stats.bytes += bytes;
            if st.asked.contains(&entry) {
                st.ready_bytes += bytes;
                st.ready.push(loaded);
            } else {
                st.stats.dropped += 1;
            }
            self.arrived.notify_all();
        }
    }
}

/// Appends an interval, merging it into the last one when they touch, and into the last one
/// anyway once the timeline is full.
fn push_interval(t: &mut Timeline, (a, b): (f64, f64)) {
    let full = t.len() >= TIMELINE_CAP;
    match t.last_mut() {
        Some(last) if a <= last.1 + 1e-4 || full => last.1 = last.1.max(b),
        _ => t.push((a, b)),
    }
}

/// Seconds during which both timelines are busy (each a sorted list of disjoint intervals).
pub fn overlap(a: &[(f64, f64)], b: &[(f64, f64)]) -> f64 {
    let (mut i, mut j, mut both) = (0, 0, 0.0);
    while i < a.len() && j < b.len() {
        let lo = a[i].0.max(b[j].0);
        let hi = a[i].1.min(b[j].1);
        if hi > lo {
            both += hi - lo;
        }
        if a[i].1 < b[j].1 {
            i += 1;
        } else {
            j += 1;
        }
    }
    both
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bricks::BrickKey;
    use crate::phantom::shepp_logan;

    fn loader(threads: usize, ready: u64) -> BrickLoader {
        let levels = Arc::new(BrickLevels::of_volume(shepp_logan(96)).unwrap());
        BrickLoader::new(levels, threads, ready)
    }

    #[test]
    fn bricks_arrive_as_they_were_read_and_in_priority_order() {
        let l = loader(1, 1 << 30);
        let levels = l.levels().clone();
        let e = |b: [usize; 3]| levels.entry(BrickKey { level: 0, brick: b });
        let asked = [(e([2, 2, 2]), 5), (e([0, 0, 0]), 1), (e([1, 0, 0]), 3)];
        l.request(&asked);
        let mut got = Vec::new();
        while got.len() < 3 {
            got.extend(l.take_at_least(3, 8, Duration::from_secs(30)));
        }
        // One loader takes the most urgent first.
        let order: Vec<usize> = got.iter().map(|g| g.entry).collect();
        assert_eq!(order, vec![e([0, 0, 0]), e([1, 0, 0]), e([2, 2, 2])]);
        let key = levels.key(order[1]).unwrap();
        assert_eq!(
            got[1].voxels.as_ref().unwrap().data,
            levels.voxels(key).unwrap().data
        );
        assert_eq!(l.outstanding(), 0);
        assert_eq!(l.stats().bricks, 3);
        let t = l.timeline(Instant::now() - Duration::from_secs(100));
        assert!(!t.is_empty() && t.iter().all(|&(a, b)| b >= a && a > 0.0));
    }

    /// Without waiting, bricks that upload nothing do not count against the most taken, within
    /// [`FREE_PER_UPLOAD`] for each that does.
    #[test]
    fn bricks_that_upload_nothing_come_on_top_of_those_that_do() {
        let l = loader(2, 1 << 30);
        let levels = l.levels().clone();
        let counts = levels.levels()[0].counts;
        let all: Vec<(usize, u64)> = (0..counts.iter().product::<usize>())
            .map(|e| (e, e as u64))
            .collect();
        l.request(&all);
        while l.outstanding() > l.stats_ready() {
            std::thread::sleep(Duration::from_millis(5));
        }
        assert_eq!(l.stats_ready(), 27);
        // Every brick free: as many as the bound on them.
        assert_eq!(l.take(2, &|_| true).len(), 2 * (FREE_PER_UPLOAD + 1));
        // One brick in two free: up to the second that uploads, with those before it.
        let flip = std::cell::Cell::new(false);
        let got = l.take(2, &|_| flip.replace(!flip.get()));
        assert_eq!(
            got.len(),
            3,
            "upload, free, upload: the second upload ends it"
        );
        // Every brick counting: two.
        assert_eq!(l.take(2, &|_| false).len(), 2);
    }

    #[test]
    fn a_new_request_replaces_the_queue_and_the_ready_bound_holds() {
        // Room for one brick ready at a time: the loader stops after it.
        let l = loader(2, 1);
        let all: Vec<(usize, u64)> = (0..27).map(|e| (e, e as u64)).collect();
        l.request(&all);
        std::thread::sleep(Duration::from_millis(300));
        // Each loader checks for room before it reads: at most one brick each is ready.
        assert!(
            l.stats().bricks <= 2,
            "{} read beyond the bound",
            l.stats().bricks
        );
        // Asked anew for two bricks only: the rest of the queue is forgotten, and what is ready
        // or being read and no longer asked for is dropped.
        l.request(&[(26, 0), (25, 1)]);
        let mut got = Vec::new();
        while l.outstanding() > 0 {
            got.extend(l.take_at_least(2, 8, Duration::from_secs(30)));
        }
        let mut entries: Vec<usize> = got.iter().map(|g| g.entry).collect();
        entries.sort();
        assert_eq!(entries, vec![25, 26]);
        assert!(l.stats().bricks <= 4, "{} read", l.stats().bricks);
    }

    #[test]
    fn waiting_for_more_than_the_ready_bound_holds_returns_once_it_is_full() {
        // Room for about one brick ready: asking for ten at least must not wait for the timeout
        // (the loaders stop at the bound, so ten never come).
        let l = loader(2, 1);
        l.request(&(0..27).map(|e| (e, e as u64)).collect::<Vec<_>>());
        let start = Instant::now();
        let got = l.take_at_least(10, 16, Duration::from_secs(600));
        assert!(!got.is_empty() && got.len() < 10, "{} bricks", got.len());
        assert!(
            start.elapsed() < Duration::from_secs(300),
            "waited {:?} for bricks that could not come",
            start.elapsed()
        );
    }

    #[test]
    fn overlap_of_two_timelines() {
        let a = [(0.0, 1.0), (2.0, 3.0)];
        let b = [(0.5, 2.5)];
        assert!((overlap(&a, &b) - 1.0).abs() < 1e-12);
        assert_eq!(overlap(&a, &[]), 0.0);
    }
}
