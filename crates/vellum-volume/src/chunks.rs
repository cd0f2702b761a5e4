//! Decoded chunks of a store, kept in a cache of bounded size that the brick loaders share
//! (issue 39).
//!
//! A brick and its apron (36³ voxels) straddle up to eight chunks of a store, and a chunk of 64³
//! holds eight bricks: read box by box, every chunk was decoded about eight times. Here each chunk
//! is decoded once while it stays in the cache, however many bricks and threads ask for it: the
//! first thread to ask decodes it, the others wait for that decode instead of repeating it. The
//! least recently used chunks leave once the decoded bytes exceed the budget (chunks in use by a
//! loader stay alive until it drops them, so the bound is exceeded by at most the chunks the
//! loaders hold at once). A chunk that fails to decode stays failed in the cache, with its
//! sentence. Each chunk says whether it holds one value throughout (found once, at its decode),
//! so that a brick inside such chunks is known without being read voxel by voxel: most of a
//! scan's bricks are air.

use crate::{Volume, VoxelData};
use std::collections::{BTreeMap, HashMap};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::Instant;
use vellum_error::{Error, Result};

/// A chunk: its level and its index in that level's chunk grid (x, y, z).
pub type ChunkKey = (usize, [usize; 3]);

type Cell = Arc<OnceLock<std::result::Result<Arc<Chunk>, String>>>;

/// A decoded chunk. A chunk whose voxels all hold one value keeps that value alone (one voxel),
/// so that the cache holds thousands of them (a scan's air) in the room of one chunk.
pub struct Chunk {
    /// The voxels, or for a chunk of one value a single voxel holding it.
    pub volume: Volume,
    /// Voxels of the chunk along x, y, z.
    pub dims: [usize; 3],
    /// Whether every voxel of the chunk has one value (then `volume` holds it once).
    pub uniform: bool,
}

impl Chunk {
    /// `volume`, its uniformity found (a scan that stops at the first block of voxels that
    /// differs from the first voxel).
    pub fn new(volume: Volume) -> Self {
        let dims = volume.dims;
        match one_value(&volume.data) {
            Some(one) => Chunk {
                volume: Volume {
                    dims: [1; 3],
                    data: one,
                    ..volume
                },
                dims,
                uniform: true,
            },
            None => Chunk {
                volume,
                dims,
                uniform: false,
            },
        }
    }

    /// The chunk of `dims` voxels decoded into `data` (a buffer the cache reuses): its one
    /// value, or the voxels `keep` makes of them (a copy, or a copy converted).
    pub fn of_decoded(
        data: &VoxelData,
        dims: [usize; 3],
        spacing: [f64; 3],
        keep: impl FnOnce(&VoxelData) -> VoxelData,
    ) -> Result<Self> {
        let (size, data, uniform) = match one_value(data) {
            Some(one) => ([1; 3], one, true),
            None => (dims, keep(data), false),
        };
        Ok(Chunk {
            volume: Volume::new(size, spacing, data)?,
            dims,
            uniform,
        })
    }

    /// A chunk of `dims` voxels of type `voxel` that all hold `value` (a value of that type: a
    /// store's fill value).
    pub fn of_value(
        value: f64,
        voxel: crate::VoxelType,
        dims: [usize; 3],
        spacing: [f64; 3],
    ) -> Result<Self> {
        use crate::VoxelType as T;
        let one = match voxel {
            T::U8 => VoxelData::U8(vec![value as u8]),
            T::U16 => VoxelData::U16(vec![value as u16]),
            T::I16 => VoxelData::I16(vec![value as i16]),
            T::F32 => VoxelData::F32(vec![value as f32]),
        };
        Ok(Chunk {
            volume: Volume::new([1; 3], spacing, one)?,
            dims,
            uniform: true,
        })
    }

    /// The value of every voxel, when there is one.
    pub fn value(&self) -> Option<f64> {
        self.uniform.then(|| self.volume.data.get_f64(0))
    }

    /// Bytes the chunk holds in memory.
    pub fn bytes(&self) -> u64 {
        self.volume.data.as_bytes().len() as u64
    }
}

/// The first voxel alone, when every voxel holds its value (blocks compared without a branch
/// per voxel, which the compiler vectorises: a chunk of one value is scanned whole, and most
/// chunks of a phantom or of CT air are).
fn one_value(data: &VoxelData) -> Option<VoxelData> {
    fn same<T: PartialEq + Copy>(s: &[T]) -> bool {
        s.first().is_none_or(|&f| {
            s.chunks(1024)
                .all(|b| b.iter().fold(true, |same, &v| same & (v == f)))
        })
    }
    let uniform = !data.is_empty()
        && match data {
            VoxelData::U8(s) => same(s),
            VoxelData::U16(s) => same(s),
            VoxelData::I16(s) => same(s),
            VoxelData::F32(s) => same(s),
        };
    uniform.then(|| match data {
        VoxelData::U8(s) => VoxelData::U8(s[..1].to_vec()),
        VoxelData::U16(s) => VoxelData::U16(s[..1].to_vec()),
        VoxelData::I16(s) => VoxelData::I16(s[..1].to_vec()),
        VoxelData::F32(s) => VoxelData::F32(s[..1].to_vec()),
    })
}

struct Entry {
    cell: Cell,
    tick: u64,
    bytes: u64,
    /// Whether the chunk holds one value, and so sits in [`Inner::small`].
    small: bool,
}

/// What the cache counts for an entry besides its voxels: its places in the maps, its cell and
/// its chunk's header (about this much; a chunk of one value is mostly this).
const ENTRY_BYTES: u64 = 256;

#[derive(Default)]
struct Inner {
    entries: HashMap<ChunkKey, Entry>,
    /// Entries by last use, oldest first: chunks being decoded or holding voxels, which leave
    /// first beyond the budget ...
    order: BTreeMap<u64, ChunkKey>,
    /// ... and then chunks of one value, which cost next to nothing to keep (a few hundred
    /// bytes, where a chunk of voxels holds a MiB) and something to decode again: in the room
    /// of one chunk of voxels the cache keeps thousands of them. Evicted by plain LRU, a large
    /// frame's absent chunks (the fill value, air) were decoded 2.4 times each.
    small: BTreeMap<u64, ChunkKey>,
    bytes: u64,
    tick: u64,
    /// The bytes kept at most for now: the budget, or less while no chunk that left is asked
    /// for again ([`ChunkCache::new`]).
    limit: u64,
    /// Chunks that left, by the tick they left at, with the bytes they held ...
    ghosts: BTreeMap<u64, (ChunkKey, u64)>,
    /// ... found by key ...
    ghost_ticks: HashMap<ChunkKey, u64>,
    /// ... and those bytes summed: at most the budget's worth are remembered.
    ghost_bytes: u64,
    /// Every chunk decoded, in order (kept only when asked: `ChunkCache::record_keys`).
    keys: Option<Vec<ChunkKey>>,
}

/// The calling thread's CPU time in milliseconds (0 where the platform does not say): the time
/// it ran, not the time it waited for a core.
pub fn thread_cpu_ms() -> f64 {
    #[cfg(unix)]
    {
        let mut ts = libc::timespec {
            tv_sec: 0,
            tv_nsec: 0,
        };
        // SAFETY: clock_gettime writes the timespec it is given and nothing else.
        if unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) } == 0 {
            return ts.tv_sec as f64 * 1e3 + ts.tv_nsec as f64 / 1e6;
        }
    }
    0.0
}

/// What the cache did: chunks decoded, their voxel bytes, the time spent decoding (summed over
/// the threads), and lookups answered from the cache.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct ChunkStats {
    /// Chunks decoded.
    pub decoded: u64,
    /// Their voxel bytes.
    pub decoded_bytes: u64,
    /// Milliseconds spent decoding chunks and keeping them, summed over the threads.
    pub decode_ms: f64,
    /// The CPU time of the decoding alone, summed over the threads: below `decode_ms` by the
    /// time the threads waited for a core ([`thread_cpu_ms`]) and by `keep_cpu_ms`.
    pub decode_cpu_ms: f64,
    /// The CPU time spent keeping the decoded chunks ([`ChunkCache::get_decoded`]'s `keep`:
    /// whether each holds one value, and a copy, or a conversion, into memory of its own, which
    /// the process touches for the first time while the cache grows), summed over the threads.
    pub keep_cpu_ms: f64,
    /// Lookups answered from the cache.
    pub(crate) hits: u64,
    /// The CPU time of the paired plain decodes ([`ChunkCache::pair_decodes`]), summed over the
    /// threads; 0 unless asked.
    pub paired_cpu_ms: f64,
    /// Their voxel bytes.
    pub paired_bytes: u64,
}

/// The bytes a cache of a larger budget keeps at first ([`ChunkCache::new`]).
const FIRST_LIMIT: u64 = 64 << 20;

/// Decoded chunks, at most about `budget` bytes of them.
pub struct ChunkCache {
    budget: u64,
    inner: Mutex<Inner>,
    decoded: AtomicU64,
    decoded_bytes: AtomicU64,
    decode_ns: AtomicU64,
    decode_cpu_ns: AtomicU64,
    keep_cpu_ns: AtomicU64,
    hits: AtomicU64,
    /// Whether each decode is paired with a plain one ([`ChunkCache::pair_decodes`]), the
    /// decodes so paired, their CPU time and bytes.
    paired: std::sync::atomic::AtomicBool,
    pairs: AtomicU64,
    paired_cpu_ns: AtomicU64,
    paired_bytes: AtomicU64,
    /// Buffers chunks were decoded into, for the next decodes ([`ChunkCache::get_decoded`]).
    spares: Mutex<Vec<(std::thread::ThreadId, VoxelData)>>,
}

impl ChunkCache {
    /// An empty cache that keeps about `budget` bytes of decoded voxels.
    ///
    /// It keeps less at first: an eighth of the budget, or 64 MiB where that is more (the whole
    /// budget, below). It grows toward the budget by twice a chunk's bytes whenever a chunk that
    /// left is asked for again, as a larger cache would have kept it; a chunk asked for once is
    /// never a reason to grow. Memory a cache takes for the first time costs the kernel's page
    /// faults (on the 2-core VM of BENCHMARKS.md, 0.4 ms a MiB, more than decoding the chunk
    /// that fills it); a still frame of a 2048³ store asks for each of its chunks in turn,
    /// mostly once, and filled 896 MiB of fresh memory where about 250 MiB held what it asked
    /// for again.
    pub fn new(budget: u64) -> Self {
        Self::starting_at(budget, budget.min((budget / 8).max(FIRST_LIMIT)))
    }

    /// An empty cache of `budget` bytes that keeps `limit` at first ([`ChunkCache::new`]).
    fn starting_at(budget: u64, limit: u64) -> Self {
        ChunkCache {
            budget,
            inner: Mutex::new(Inner {
                limit,
                ..Inner::default()
            }),
            decoded: AtomicU64::new(0),
            decoded_bytes: AtomicU64::new(0),
            decode_ns: AtomicU64::new(0),
            decode_cpu_ns: AtomicU64::new(0),
            keep_cpu_ns: AtomicU64::new(0),
            hits: AtomicU64::new(0),
            paired: false.into(),
            pairs: AtomicU64::new(0),
            paired_cpu_ns: AtomicU64::new(0),
            paired_bytes: AtomicU64::new(0),
            spares: Mutex::new(Vec::new()),
        }
    }

    /// The bytes of decoded voxels the cache keeps at most.
    pub fn budget(&self) -> u64 {
        self.budget
    }

    /// Chunk `key` (of about `bytes` bytes decoded): from the cache, or from `decode`, run once
    /// however many threads ask for the chunk at the same time.
    #[cfg(test)]
    pub(crate) fn get(
        &self,
        key: ChunkKey,
        bytes: u64,
        decode: impl FnOnce() -> Result<Volume>,
    ) -> Result<Arc<Chunk>> {
        self.get_chunk(key, bytes, || {
            self.timed(&self.decode_cpu_ns, || decode().map(Chunk::new))
        })
    }

    /// Chunk `key`, of `n` voxels of type `voxel`, as [`ChunkCache::get`] gives it, but
    /// decoded by `decode` into a buffer the cache reuses, and then kept by `keep`
    /// ([`Chunk::of_decoded`]): a chunk of one value is then kept without a buffer of its own
    /// ever being made for it, and one of many values is copied (or converted) out once. The
    /// two are timed apart ([`ChunkStats::keep_cpu_ms`]).
    pub fn get_decoded(
        &self,
        key: ChunkKey,
        (voxel, n): (crate::VoxelType, usize),
        decode: impl Fn(&mut VoxelData) -> Result<()>,
        keep: impl FnOnce(&VoxelData) -> Result<Chunk>,
    ) -> Result<Arc<Chunk>> {
        let bytes = (n * voxel.size()) as u64;
        self.get_chunk(key, bytes, || {
            // A paired decode goes first every other time, so that neither of the two is
            // always the one that finds the chunk's bytes in the caches.
            let pair = self.paired.load(Ordering::Relaxed);
            let first = pair && self.pairs.fetch_add(1, Ordering::Relaxed).is_multiple_of(2);
            if first {
                self.paired_decode((voxel, n), &decode)?;
            }
            let mut buf = self.spare(voxel, n);
            let decoded = self.timed(&self.decode_cpu_ns, || decode(&mut buf));
            let chunk = decoded.and_then(|()| self.timed(&self.keep_cpu_ns, || keep(&buf)));
            self.keep_spare(buf);
            if pair && !first && chunk.is_ok() {
                self.paired_decode((voxel, n), &decode)?;
            }
            chunk
        })
    }

    /// From now on, pairs every decode of [`ChunkCache::get_decoded`] with a plain one by the
    /// same thread, into a buffer of its own that it reuses, timed apart
    /// ([`ChunkStats::paired_cpu_ms`]), and nothing kept: a benchmark's floor, measured beside
    /// the cache's decodes, under the same load from the rest of the process and the machine.
    pub fn pair_decodes(&self) {
        self.paired.store(true, Ordering::Relaxed);
    }

    /// A paired decode ([`ChunkCache::pair_decodes`]).
    fn paired_decode(
        &self,
        (voxel, n): (crate::VoxelType, usize),
        decode: &impl Fn(&mut VoxelData) -> Result<()>,
    ) -> Result<()> {
        thread_local! {
            static PLAIN: std::cell::RefCell<VoxelData> =
                const { std::cell::RefCell::new(VoxelData::U8(Vec::new())) };
        }
        PLAIN.with_borrow_mut(|buf| {
            buf.fit(voxel, n);
            self.timed(&self.paired_cpu_ns, || decode(buf))?;
            self.paired_bytes
                .fetch_add(buf.as_bytes().len() as u64, Ordering::Relaxed);
            Ok(())
        })
    }

    /// `f`, its CPU time added to `cpu_ns`.
    fn timed<R>(&self, cpu_ns: &AtomicU64, f: impl FnOnce() -> R) -> R {
        let cpu = thread_cpu_ms();
        let r = f();
        let ns = ((thread_cpu_ms() - cpu) * 1e6) as u64;
        cpu_ns.fetch_add(ns, Ordering::Relaxed);
        r
    }

    /// A buffer of `n` voxels of type `voxel` from the spares (its old voxels are overwritten
    /// by the decode), else a new one.
    ///
    /// The calling thread gets back the buffer it kept last where it kept one; another thread's
    /// only where it did not. A buffer that moves between threads moves between cores: on the
    /// 2-core VM of BENCHMARKS.md, in about one run in three, zstd decoded 1.7 times slower into
    /// buffers handed from thread to thread than into a buffer of the thread's own (sixteenth
    /// round).
    fn spare(&self, voxel: crate::VoxelType, n: usize) -> VoxelData {
        let mut spares = self.spares.lock().unwrap_or_else(|p| p.into_inner());
        let me = std::thread::current().id();
        let mine = spares
            .iter()
            .rposition(|(t, b)| *t == me && b.fits(voxel, n));
        match mine.or_else(|| spares.iter().rposition(|(_, b)| b.fits(voxel, n))) {
            Some(i) => spares.remove(i).1,
            None => VoxelData::zeros(voxel, n),
        }
    }

    /// Keeps `buf` for the next decode, the longest kept spares leaving while they would hold more
    /// than a sixteenth of the budget (56 MiB of the default 896: a buffer for each of sixteen
    /// loaders decoding at once, with chunks of up to 3.5 MiB). A buffer of an edge chunk's
    /// shape thus does not keep out those of whole chunks for long.
    fn keep_spare(&self, buf: VoxelData) {
        let bytes = buf.as_bytes().len() as u64;
        if bytes > self.budget / 16 {
            return;
        }
        let mut spares = self.spares.lock().unwrap_or_else(|p| p.into_inner());
        let mut held: u64 = spares.iter().map(|b| b.1.as_bytes().len() as u64).sum();
        while held + bytes > self.budget / 16 && !spares.is_empty() {
            held -= spares.remove(0).1.as_bytes().len() as u64;
        }
        spares.push((std::thread::current().id(), buf));
    }

    /// [`ChunkCache::get`] with the chunk made by `make`.
    fn get_chunk(
        &self,
        key: ChunkKey,
        bytes: u64,
        make: impl FnOnce() -> Result<Chunk>,
    ) -> Result<Arc<Chunk>> {
        let (cell, fresh) = self.cell(key, bytes);
        let mut ran = false;
        let got = cell.get_or_init(|| {
            ran = true;
            let start = Instant::now();
            let r = make().map(Arc::new).map_err(|e| e.to_string());
            self.decode_ns
                .fetch_add(start.elapsed().as_nanos() as u64, Ordering::Relaxed);
            if r.is_ok() {
                self.decoded.fetch_add(1, Ordering::Relaxed);
                self.decoded_bytes.fetch_add(bytes, Ordering::Relaxed);
            }
            r
        });
        if !ran && !fresh {
            self.hits.fetch_add(1, Ordering::Relaxed);
        }
        if let (true, Ok(c)) = (ran, got) {
            self.settle(key, &cell, c);
        }
        got.clone().map_err(Error::Invalid)
    }

    /// Counts `key`'s entry at what its decoded `chunk` holds (a chunk of one value keeps one
    /// voxel, and moves to [`Inner::small`]), if the entry is still the one holding `cell`.
    fn settle(&self, key: ChunkKey, cell: &Cell, chunk: &Chunk) {
        let mut inner = self.inner.lock().unwrap_or_else(|p| p.into_inner());
        let bytes = chunk.bytes() + ENTRY_BYTES;
        let Some(e) = inner.entries.get_mut(&key) else {
            return;
        };
        if !Arc::ptr_eq(&e.cell, cell) {
            return;
        }
        let old = std::mem::replace(&mut e.bytes, bytes);
        let tick = e.tick;
        e.small = chunk.uniform;
        inner.bytes = inner.bytes - old + bytes;
        if chunk.uniform && inner.order.remove(&tick).is_some() {
            inner.small.insert(tick, key);
        }
    }

    /// The cell of `key`, made (and the cache trimmed to its budget) when it was missing; and
    /// whether it was.
    fn cell(&self, key: ChunkKey, bytes: u64) -> (Cell, bool) {
        // Counted as `settle` will count it once decoded (at its full size until then).
        let bytes = bytes + ENTRY_BYTES;
        let mut inner = self.inner.lock().unwrap_or_else(|p| p.into_inner());
        inner.tick += 1;
        let tick = inner.tick;
        if let Some(e) = inner.entries.get_mut(&key) {
            let old = std::mem::replace(&mut e.tick, tick);
            let (cell, small) = (e.cell.clone(), e.small);
            let order = match small {
                true => &mut inner.small,
                false => &mut inner.order,
            };
            order.remove(&old);
            order.insert(tick, key);
            return (cell, false);
        }
        let cell: Cell = Arc::new(OnceLock::new());
        if let Some(keys) = &mut inner.keys {
            keys.push(key);
        }
        if let Some(left) = inner.ghost_ticks.remove(&key) {
            let (_, held) = inner.ghosts.remove(&left).unwrap_or_default();
            inner.ghost_bytes -= held;
            inner.limit = self.budget.min(inner.limit + 2 * held);
        }
        inner.entries.insert(
            key,
            Entry {
                cell: cell.clone(),
                tick,
                bytes,
                small: false,
            },
        );
        inner.order.insert(tick, key);
        inner.bytes += bytes;
        // The new entry is the last of `order`, and stays.
        while inner.bytes > inner.limit {
            let oldest = match inner.order.len() > 1 {
                true => inner.order.pop_first(),
                false => inner.small.pop_first(),
            };
            let Some((_, oldest)) = oldest else {
                break;
            };
            if let Some(e) = inner.entries.remove(&oldest) {
                inner.bytes -= e.bytes;
                self.remember(&mut inner, oldest, e.bytes);
            }
        }
        (cell, true)
    }

    /// Remembers that `key`, of `bytes`, left, forgetting the chunks that left longest ago
    /// beyond the budget's worth.
    fn remember(&self, inner: &mut Inner, key: ChunkKey, bytes: u64) {
        inner.tick += 1;
        let tick = inner.tick;
        inner.ghosts.insert(tick, (key, bytes));
        inner.ghost_ticks.insert(key, tick);
        inner.ghost_bytes += bytes;
        while inner.ghost_bytes > self.budget {
            let Some((_, (old, held))) = inner.ghosts.pop_first() else {
                break;
            };
            inner.ghost_ticks.remove(&old);
            inner.ghost_bytes -= held;
        }
    }

    /// The bytes the cache keeps at most for now (at most its budget).
    #[cfg(test)]
    pub(crate) fn limit(&self) -> u64 {
        self.inner.lock().unwrap_or_else(|p| p.into_inner()).limit
    }

    /// What the cache has done so far.
    pub fn stats(&self) -> ChunkStats {
        ChunkStats {
            decoded: self.decoded.load(Ordering::Relaxed),
            decoded_bytes: self.decoded_bytes.load(Ordering::Relaxed),
            decode_ms: self.decode_ns.load(Ordering::Relaxed) as f64 / 1e6,
            decode_cpu_ms: self.decode_cpu_ns.load(Ordering::Relaxed) as f64 / 1e6,
            keep_cpu_ms: self.keep_cpu_ns.load(Ordering::Relaxed) as f64 / 1e6,
            hits: self.hits.load(Ordering::Relaxed),
            paired_cpu_ms: self.paired_cpu_ns.load(Ordering::Relaxed) as f64 / 1e6,
            paired_bytes: self.paired_bytes.load(Ordering::Relaxed),
        }
    }

    /// From now on, keeps the key of every chunk decoded (for a benchmark's floor: the same
    /// chunks decoded again plainly, `BrickLevels::plain_decode`).
    pub fn record_keys(&self) {
        let mut inner = self.inner.lock().unwrap_or_else(|p| p.into_inner());
        inner.keys.get_or_insert_with(Vec::new);
    }

    /// The keys recorded since [`ChunkCache::record_keys`], distinct, in the order first decoded.
    pub fn recorded_keys(&self) -> Vec<ChunkKey> {
        let inner = self.inner.lock().unwrap_or_else(|p| p.into_inner());
        let mut seen = std::collections::HashSet::new();
        let keys = inner.keys.as_deref().unwrap_or_default();
        keys.iter().copied().filter(|k| seen.insert(*k)).collect()
    }

    /// Chunks held now and their bytes.
    #[cfg(test)]
    pub(crate) fn held(&self) -> (usize, u64) {
        let inner = self.inner.lock().unwrap_or_else(|p| p.into_inner());
        (inner.entries.len(), inner.bytes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::AtomicUsize;

    /// A chunk of eight voxels, `v` first (not one value).
    fn chunk(v: u8) -> Result<Volume> {
        let d = (0..8).map(|i| v.wrapping_add(i)).collect();
        Volume::new([2, 2, 2], [1.0; 3], VoxelData::U8(d))
    }

    fn first(c: &Chunk) -> f64 {
        c.volume.data.get_f64(0)
    }

    /// The decoding's CPU time counts the time a decode ran, not the time it waited: a decode
    /// that sleeps adds its wall time to `decode_ms` and next to nothing to `decode_cpu_ms`; one
    /// that computes adds to both.
    #[test]
    #[cfg(unix)]
    fn decoding_is_measured_in_wall_and_cpu_time() {
        let cache = ChunkCache::new(1 << 20);
        let sleep = std::time::Duration::from_millis(30);
        cache
            .get((0, [0; 3]), 8, || {
                std::thread::sleep(sleep);
                chunk(1)
            })
            .unwrap();
        let slept = cache.stats();
        assert!(slept.decode_ms >= 30.0, "{slept:?}");
        assert!(slept.decode_cpu_ms < 15.0, "{slept:?}");
        cache
            .get((0, [1; 3]), 8, || {
                let start = thread_cpu_ms();
                let mut x = 1u64;
                while thread_cpu_ms() - start < 5.0 {
                    x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
                }
                chunk(2)
            })
            .unwrap();
        let worked = cache.stats();
        let cpu = worked.decode_cpu_ms - slept.decode_cpu_ms;
        let wall = worked.decode_ms - slept.decode_ms;
        assert!(cpu >= 5.0 && cpu <= wall + 0.5, "{worked:?}");
    }

    #[test]
    fn a_chunk_is_decoded_once_while_it_stays() {
        let cache = ChunkCache::new(64);
        let runs = AtomicUsize::new(0);
        let decode = |v| {
            runs.fetch_add(1, Ordering::Relaxed);
            chunk(v)
        };
        for _ in 0..3 {
            let c = cache.get((0, [1, 2, 3]), 8, || decode(7)).unwrap();
            assert_eq!((first(&c), c.dims, c.uniform), (7.0, [2; 3], false));
        }
        assert_eq!(runs.load(Ordering::Relaxed), 1);
        assert_eq!(cache.stats().hits, 2);
        assert_eq!(cache.stats().decoded_bytes, 8);
    }

    #[test]
    fn the_least_recently_used_chunks_leave_beyond_the_budget() {
        let cache = ChunkCache::new(3 * (8 + ENTRY_BYTES));
        for i in 0..3 {
            cache.get((0, [i, 0, 0]), 8, || chunk(i as u8)).unwrap();
        }
        // Chunk 0 used again: chunk 1 is now the oldest, and the fourth pushes it out.
        cache.get((0, [0, 0, 0]), 8, || chunk(9)).unwrap();
        cache.get((0, [3, 0, 0]), 8, || chunk(3)).unwrap();
        assert_eq!(cache.held(), (3, 3 * (8 + ENTRY_BYTES)));
        let again = cache.get((0, [1, 0, 0]), 8, || chunk(11)).unwrap();
        assert_eq!(first(&again), 11.0, "decoded anew");
        let kept = cache.get((0, [0, 0, 0]), 8, || chunk(12)).unwrap();
        assert_eq!(first(&kept), 0.0, "still the first decode");
    }

    /// The cache keeps less than its budget until chunks that left are asked for again: a
    /// scan of chunks asked for once stays within the first limit, and a cycle over more chunks
    /// than that grows it until the cycle fits, never beyond the budget.
    #[test]
    fn the_cache_grows_toward_its_budget_when_chunks_that_left_come_back() {
        let one = 4096 + ENTRY_BYTES;
        let cache = ChunkCache::starting_at(8 * one, 3 * one);
        for i in 0..20 {
            cache.get((0, [i, 0, 0]), 4096, || many(i as u8)).unwrap();
        }
        assert_eq!((cache.limit(), cache.held()), (3 * one, (3, 3 * one)));
        // Five chunks in turn, again and again: each one that left and comes back grows the
        // limit by two chunks, until all five stay.
        let runs = AtomicUsize::new(0);
        for _ in 0..4 {
            for i in 100..105 {
                cache
                    .get((0, [i, 0, 0]), 4096, || {
                        runs.fetch_add(1, Ordering::Relaxed);
                        many(i as u8)
                    })
                    .unwrap();
            }
        }
        assert_eq!(cache.limit(), 7 * one, "grown by two chunks twice");
        assert_eq!(
            runs.load(Ordering::Relaxed),
            7,
            "five, then two decoded again"
        );
        // Ten in turn: it grows to the budget and no further.
        for _ in 0..3 {
            for i in 200..210 {
                cache.get((0, [i, 0, 0]), 4096, || many(i as u8)).unwrap();
            }
        }
        assert_eq!(cache.limit(), 8 * one);
        assert!(cache.held().1 <= 8 * one);
    }

    #[test]
    fn threads_asking_for_one_chunk_share_one_decode() {
        let cache = ChunkCache::new(1 << 20);
        let runs = AtomicUsize::new(0);
        std::thread::scope(|s| {
            for _ in 0..8 {
                s.spawn(|| {
                    cache
                        .get((2, [0, 0, 0]), 8, || {
                            runs.fetch_add(1, Ordering::Relaxed);
                            std::thread::sleep(std::time::Duration::from_millis(20));
                            chunk(1)
                        })
                        .unwrap();
                });
            }
        });
        assert_eq!(runs.load(Ordering::Relaxed), 1);
    }

    /// A chunk of 16³ voxels of one value `v`.
    fn flat(v: u8) -> Result<Volume> {
        Volume::new([16; 3], [1.0; 3], VoxelData::U8(vec![v; 4096]))
    }

    /// A chunk of 16³ voxels, `v` first (not one value).
    fn many(v: u8) -> Result<Volume> {
        let d = (0..4096).map(|i| v.wrapping_add(i as u8)).collect();
        Volume::new([16; 3], [1.0; 3], VoxelData::U8(d))
    }

    #[test]
    fn chunks_of_one_value_are_held_as_one_voxel_and_leave_after_the_others() {
        // Room for three chunks of many values.
        let cache = ChunkCache::new(3 * (4096 + ENTRY_BYTES));
        for i in 0..10 {
            let c = cache.get((0, [i, 0, 0]), 4096, || flat(i as u8)).unwrap();
            assert_eq!((c.value(), c.dims, c.bytes()), (Some(i as f64), [16; 3], 1));
        }
        let small = 10 * (1 + ENTRY_BYTES);
        assert_eq!(cache.held(), (10, small), "ten chunks in the room of one");
        // Beyond the budget, the chunks of many values leave, oldest first: those of one value,
        // older still, stay.
        for i in 10..14 {
            cache.get((0, [i, 0, 0]), 4096, || many(i as u8)).unwrap();
        }
        assert_eq!(cache.held(), (12, small + 2 * (4096 + ENTRY_BYTES)));
        for i in 0..10 {
            let c = cache.get((0, [i, 0, 0]), 4096, || flat(99)).unwrap();
            assert_eq!(c.value(), Some(i as f64), "chunk {i} decoded again");
        }
        let again = cache.get((0, [10, 0, 0]), 4096, || many(99)).unwrap();
        assert_eq!(first(&again), 99.0, "the oldest chunk of many values left");
    }

    #[test]
    fn chunks_of_one_value_leave_by_last_use_when_they_fill_the_budget() {
        // Room for three of them and a chunk being decoded, counted at its full size until it
        // is known to hold one value.
        let cache = ChunkCache::new(3 * (1 + ENTRY_BYTES) + 4096 + ENTRY_BYTES);
        for i in 0..5 {
            cache.get((0, [i, 0, 0]), 4096, || flat(i as u8)).unwrap();
        }
        assert_eq!(cache.held(), (4, 4 * (1 + ENTRY_BYTES)));
        let again = cache.get((0, [0, 0, 0]), 4096, || flat(99)).unwrap();
        assert_eq!(again.value(), Some(99.0), "decoded anew");
    }

    #[test]
    fn chunks_decoded_into_a_reused_buffer_are_what_was_decoded() {
        let cache = ChunkCache::new(1 << 20);
        let shape = (crate::VoxelType::U8, 4096);
        let keep = |buf: &VoxelData| Chunk::of_decoded(buf, [16; 3], [1.0; 3], VoxelData::clone);
        let into = |v: fn(u8) -> Result<Volume>, x: u8| {
            move |buf: &mut VoxelData| {
                *buf = v(x)?.data;
                Ok(())
            }
        };
        let a = cache
            .get_decoded((0, [0; 3]), shape, into(many, 5), keep)
            .unwrap();
        assert_eq!(
            (a.uniform, a.volume.data.clone()),
            (false, many(5).unwrap().data)
        );
        // The second decode is handed the first one's buffer, voxels and all.
        let b = cache
            .get_decoded(
                (0, [1, 0, 0]),
                shape,
                |buf| {
                    assert_eq!(*buf, many(5).unwrap().data, "a buffer of its own");
                    into(flat, 3)(buf)
                },
                keep,
            )
            .unwrap();
        assert_eq!((b.value(), b.dims, b.bytes()), (Some(3.0), [16; 3], 1));
        let c = Chunk::of_value(3.0, crate::VoxelType::U8, [16; 3], [1.0; 3]).unwrap();
        assert_eq!(
            (c.value(), c.dims, c.volume.data),
            (b.value(), b.dims, b.volume.data.clone())
        );
        // A decode that fails is not kept, and says why.
        let bad = |_: &mut VoxelData| Err(Error::Invalid("chunk 0/c/9 is broken".into()));
        let e = cache.get_decoded((0, [9, 0, 0]), shape, bad, keep).err();
        assert!(e.is_some_and(|e| e.to_string().contains("0/c/9")));
    }

    #[test]
    fn a_thread_is_handed_back_the_buffer_it_decoded_into_last() {
        let cache = ChunkCache::new(1 << 20);
        let (voxel, n) = (crate::VoxelType::U8, 4096);
        // Another thread keeps a buffer of the same shape before this one does.
        std::thread::scope(|s| {
            s.spawn(|| cache.keep_spare(VoxelData::zeros(voxel, n)));
        });
        let here = VoxelData::zeros(voxel, n);
        let ours = here.as_bytes().as_ptr();
        cache.keep_spare(here);
        assert_eq!(cache.spares.lock().unwrap().len(), 2);
        assert_eq!(cache.spare(voxel, n).as_bytes().as_ptr(), ours);
        // With none of its own left, a thread takes another's.
        assert!(cache.spare(voxel, n).len() == n);
        assert!(cache.spares.lock().unwrap().is_empty());
    }

    #[test]
    fn a_paired_decode_decodes_each_chunk_again_and_keeps_nothing_of_it() {
        let cache = ChunkCache::new(1 << 20);
        let keep = |buf: &VoxelData| Chunk::of_decoded(buf, [16; 3], [1.0; 3], VoxelData::clone);
        let calls = AtomicU64::new(0);
        let decode = |i: usize| {
            let calls = &calls;
            move |buf: &mut VoxelData| {
                calls.fetch_add(1, Ordering::Relaxed);
                *buf = many(i as u8)?.data;
                Ok(())
            }
        };
        let shape = (crate::VoxelType::U8, 4096);
        cache
            .get_decoded((0, [0; 3]), shape, decode(0), keep)
            .unwrap();
        assert_eq!(cache.stats().paired_bytes, 0);
        cache.pair_decodes();
        for i in 1..4 {
            let c = cache.get_decoded((0, [i, 0, 0]), shape, decode(i), keep);
            assert_eq!(c.unwrap().volume.data, many(i as u8).unwrap().data);
        }
        // A chunk the cache holds is neither decoded nor paired again.
        cache
            .get_decoded((0, [1, 0, 0]), shape, decode(1), keep)
            .unwrap();
        let stats = cache.stats();
        assert_eq!(calls.load(Ordering::Relaxed), 1 + 2 * 3);
        assert_eq!((stats.decoded, stats.paired_bytes), (4, 3 * 4096));
        assert_eq!(cache.held().0, 4);
    }

    #[test]
    fn a_chunk_knows_whether_it_holds_one_value() {
        let one = Chunk::new(Volume::new([2, 2, 2], [1.0; 3], VoxelData::U8(vec![3; 8])).unwrap());
        assert_eq!(one.value(), Some(3.0));
        let mut v = vec![0.5f32; 8];
        v[7] = 0.25;
        let two = Chunk::new(Volume::new([2, 2, 2], [1.0; 3], VoxelData::F32(v)).unwrap());
        assert_eq!((two.uniform, two.value()), (false, None));
        // NaN equals nothing, itself included: never taken for one value.
        let nan = vec![f32::NAN; 8];
        let nan = Chunk::new(Volume::new([2, 2, 2], [1.0; 3], VoxelData::F32(nan)).unwrap());
        assert_eq!(nan.value(), None);
    }

    #[test]
    fn a_failed_chunk_keeps_its_sentence() {
        let cache = ChunkCache::new(64);
        let bad = || Err(Error::Invalid("chunk 0/c/0/0/1 could not be read".into()));
        let e = cache.get((0, [1, 0, 0]), 8, bad).err().unwrap();
        assert!(e.to_string().contains("0/c/0/0/1"));
        let e = cache.get((0, [1, 0, 0]), 8, || chunk(1)).err().unwrap();
        assert!(e.to_string().contains("0/c/0/0/1"), "not decoded again");
    }
}
