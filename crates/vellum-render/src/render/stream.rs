//! The one brick streamer (issue 39), between the frames' feedback and the brick loaders: what
//! a frame's rays asked for becomes the loaders' request, in priority order, and the bricks that
//! arrived get slots in the cache and go up with the next frame. A still frame
//! (`render::bricked`) and the viewer use it alike; the still frame waits for arrivals, the viewer
//! never does.
//!
//! Priorities: a still frame asks front to back (the bricks nearest the eye first: rays wait
//! there, and a brick read in visibility order is used by every ray that needs it before it can
//! be evicted); the viewer asks coarse levels first, then front to back (a whole coarse picture
//! before a sharp corner of it).

use crate::passes::paging::{Paged, PagedVolume, Upload};
use crate::render::view::{FrameCamera, View, WorldBox};
use std::collections::HashSet;
use std::sync::Arc;
use std::time::Duration;
use vellum_error::Result;
use vellum_volume::bricks::{Arrival, BrickCache, BrickLevels, BrickVoxels, Placement};
use vellum_volume::stream::{BrickLoader, Loaded, LoaderStats};

/// How a streamer orders what the rays asked for.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum Order {
    /// Nearest the eye first, whatever the level (a still frame).
    FrontToBack,
    /// Coarse levels first, then nearest the eye (the viewer).
    CoarseFirst,
}

/// How many loaders read bricks and how many bytes of bricks may wait ready.
#[derive(Copy, Clone, Debug)]
pub struct StreamOptions {
    /// Loader threads reading bricks (at least one is started).
    pub threads: usize,
    /// At most about this many bytes of read bricks are held ready to upload.
    pub ready_bytes: u64,
}

impl Default for StreamOptions {
    fn default() -> Self {
        StreamOptions {
            threads: BrickLoader::default_threads(),
            ready_bytes: DEFAULT_READY_BYTES,
        }
    }
}

/// Bytes of bricks that may wait ready to upload by default: about 1,400 bricks at 16 bits.
pub(crate) const DEFAULT_READY_BYTES: u64 = 128 << 20;

/// A brick that arrived and has a slot: what to upload with the next frame.
pub struct Arrived {
    /// The pool slot it was placed in.
    pub slot: usize,
    /// Its page-table entry.
    pub entry: usize,
    /// Its voxels as they travel to the GPU.
    pub voxels: BrickVoxels,
}

impl Arrived {
    /// The brick as an upload for [`PagedVolume::record_loads`], borrowing its voxels.
    pub fn upload(&self) -> Upload<'_> {
        Upload {
            slot: self.slot,
            entry: self.entry,
            voxels: &self.voxels,
        }
    }
}

/// What one call of [`Streamer::arrivals`] placed: the bricks to upload, and how many bricks were
/// placed in all (those sharing the slot of their constant value upload nothing).
#[derive(Default)]
pub struct Batch {
    /// The bricks that need an upload with the next frame.
    pub uploads: Vec<Arrived>,
    /// Bricks placed in all, uploads included.
    pub placed: usize,
}

/// The loaders of one volume and what they were asked.
pub struct Streamer {
    loader: BrickLoader,
    /// Every brick asked for since the streamer started (the distinct bricks a frame touched).
    pub(crate) asked: HashSet<usize>,
    /// Bricks that arrived and were placed, those that needed an upload, and their bytes.
    pub placed: u64,
    /// Bricks placed per level, finest first.
    pub per_level: Vec<u64>,
    /// Placed bricks that needed an upload (not sharing the slot of a constant value).
    pub uploaded: u64,
    /// Bytes of the voxels of those uploads.
    pub uploaded_bytes: u64,
    /// Bricks that could not be read: never asked again. The first one's sentence.
    failed: HashSet<usize>,
    /// Why the first brick that could not be read failed, as one sentence.
    pub failure: Option<String>,
}

impl Streamer {
    /// Loaders on `levels`.
    pub fn new(levels: Arc<BrickLevels>, opts: StreamOptions) -> Self {
        Streamer {
            per_level: vec![0; levels.levels().len()],
            loader: BrickLoader::new(levels, opts.threads, opts.ready_bytes),
            asked: HashSet::new(),
            placed: 0,
            uploaded: 0,
            uploaded_bytes: 0,
            failed: HashSet::new(),
            failure: None,
        }
    }

    /// The loaders.
    pub(crate) fn loader(&self) -> &BrickLoader {
        &self.loader
    }

    /// What the loaders did so far.
    pub fn stats(&self) -> LoaderStats {
        self.loader.stats()
    }

    /// Asks for the coarsest level first of all: the fallback every sample has.
    pub fn start(&mut self, paged: &Paged) {
        let pinned: Vec<(usize, u64)> = BrickCache::pinned_entries(&paged.levels)
            .into_iter()
            .filter(|&e| !paged.cache.is_resident(e))
            .map(|e| (e, 0))
            .collect();
        self.asked.extend(pinned.iter().map(|p| p.0));
        self.loader.add(&pinned);
    }

    /// Asks for the bricks the rays of a frame seen by `view` asked for (`wanted`: entry, rays),
    /// in `order`, replacing what was asked before (the coarsest level stays asked until it is
    /// resident). Resident bricks and failed ones are left out.
    pub fn request(&mut self, paged: &Paged, view: &View, wanted: &[(usize, u32)], order: Order) {
        let place = Placement3::new(paged, view);
        let mut asks: Vec<(usize, u64)> = wanted
            .iter()
            .filter(|(e, _)| !paged.cache.is_resident(*e) && !self.failed.contains(e))
            .map(|&(e, _)| (e, place.priority(&paged.levels, e, order)))
            .collect();
        asks.extend(
            BrickCache::pinned_entries(&paged.levels)
                .into_iter()
                .filter(|&e| !paged.cache.is_resident(e))
                .map(|e| (e, 0)),
        );
        self.asked.extend(asks.iter().map(|a| a.0));
        self.loader.request(&asks);
    }

    /// The bricks that arrived, at most `max`, placed in `paged`'s cache; with `wait`, waiting
    /// until at least that many are ready (or all that was asked for, or the time is out).
    /// Without, bricks that would share a slot already made for their value do not count
    /// against `max` (`BrickLoader::take`): they upload nothing. A brick
    /// that could not be read is an error when `strict`, else left out (and never asked again,
    /// [`Streamer::failure`] saying why).
    pub fn arrivals(
        &mut self,
        paged: &mut Paged,
        max: usize,
        wait: Option<(usize, Duration)>,
        strict: bool,
    ) -> Result<Batch> {
        let got: Vec<Loaded> = match wait {
            Some((min, timeout)) => self.loader.take_at_least(min, max, timeout),
            None => {
                let cache = &paged.cache;
                self.loader.take(max, &|v| cache.shares_a_slot(v))
            }
        };
        let mut ok = Vec::with_capacity(got.len());
        for l in got {
            match l.voxels {
                Ok(v) => ok.push((l.entry, v)),
                Err(e) if strict => return Err(e),
                Err(e) => {
                    self.failed.insert(l.entry);
                    self.failure.get_or_insert_with(|| e.to_string());
                }
            }
        }
        let batch: Vec<Arrival> = ok.iter().map(|(e, v)| Arrival::of(*e, v)).collect();
        let placed = paged.cache.place(&batch);
        let mixed = paged.levels.mixed_count();
        for (e, v) in &ok {
            let known = paged.channel_ranges.get_mut(e * mixed..(e + 1) * mixed);
            if let Some(known) = known.filter(|k| k.len() == v.channel_ranges.len()) {
                known.copy_from_slice(&v.channel_ranges);
            }
        }
        let mut out = Batch::default();
        for ((entry, voxels), p) in ok.into_iter().zip(placed) {
            match p {
                Some(Placement::Upload(slot)) => {
                    self.uploaded += 1;
                    self.uploaded_bytes += voxels.travel_bytes();
                    out.uploads.push(Arrived {
                        slot,
                        entry,
                        voxels,
                    });
                }
                Some(Placement::Shared(_)) => {}
                None => continue,
            }
            self.placed += 1;
            out.placed += 1;
            if let Some(k) = paged.levels.key(entry) {
                self.per_level[k.level] += 1;
            }
        }
        Ok(out)
    }

    /// Bricks asked for and not yet placed.
    pub fn outstanding(&self) -> usize {
        self.loader.outstanding()
    }
}

/// Records the uploads of `arrived` into `vol`'s pools (pass `brick_upload`).
pub fn record_arrivals(
    vol: &PagedVolume,
    ctx: &vellum_gpu::Context,
    frame: &mut vellum_gpu::Frame,
    arrived: &[Arrived],
) -> Result<()> {
    let uploads: Vec<Upload> = arrived.iter().map(Arrived::upload).collect();
    vol.record_loads(ctx, frame, &uploads)
}

/// Where the eye is, for the priorities of one request.
struct Placement3 {
    eye: glam::Vec3,
    half: glam::Vec3,
}

impl Placement3 {
    fn new(paged: &Paged, view: &View) -> Self {
        let l0 = &paged.levels.levels()[0];
        let world = WorldBox::new(l0.dims, l0.spacing, &paged.levels.geometry);
        let camera = FrameCamera::new(&world, view);
        Placement3 {
            eye: camera.eye,
            half: world.half,
        }
    }

    /// The priority of brick `entry` (smaller first): the distance from the eye in the box
    /// frame of the centre of the store's chunk that holds the brick's centre, after its level
    /// when coarse levels go first. The bricks of one chunk come one after another, so that the
    /// chunk is decoded once for all of them.
    fn priority(&self, levels: &BrickLevels, entry: usize, order: Order) -> u64 {
        let Some(key) = levels.key(entry) else {
            return u64::MAX;
        };
        let all = levels.levels();
        let (l0, l) = (&all[0], &all[key.level]);
        let grain = levels.grain(key.level);
        let centre = glam::Vec3::from_array(std::array::from_fn(|a| {
            let mid = key.brick[a] * vellum_volume::bricks::BRICK + 16;
            let cell = (mid / grain[a]) * grain[a];
            let voxel = (cell as f64 + 0.5 * grain[a] as f64).min(l.dims[a] as f64);
            // The level's voxel in level 0's texture coordinates, then the box frame.
            let tex = voxel * l.spacing[a] / (l0.dims[a] as f64 * l0.spacing[a]);
            ((tex - 0.5) * 2.0) as f32
        })) * self.half;
        let distance = (centre - self.eye).length().max(0.0);
        let near = distance.to_bits() as u64;
        match order {
            Order::FrontToBack => near,
            Order::CoarseFirst => ((all.len() - 1 - key.level) as u64) << 32 | near,
        }
    }
}

/// The floor a still frame's streaming is judged against, measured in the same run: the chunks
/// it decoded, decoded again plainly in parallel on every core, and their bytes uploaded to the
/// device (64 MiB at a time, host-visible memory to device-local).
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct Floor {
    /// Store chunks the frame decoded.
    pub chunks: usize,
    /// Their voxel bytes once decoded: the amount the upload floor copies.
    pub bytes: u64,
    /// Milliseconds to decode them again in parallel on every core.
    pub(crate) decode_ms: f64,
    /// The CPU time of that decoding, summed over the threads.
    pub(crate) decode_cpu_ms: f64,
    /// Milliseconds to copy `bytes` from host-visible to device-local memory.
    pub upload_ms: f64,
    /// Where the frame's decodes were paired with plain ones (`VELLUM_STREAM_FLOOR=paired`,
    /// `ChunkCache::pair_decodes`): the CPU time of those plain decodes, summed over the
    /// threads, and their bytes. They ran beside the frame, under its load; the decodes above
    /// ran after it, alone.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(crate) paired: Option<Paired>,
}

/// The plain decodes paired with a frame's ([`Floor::paired`]).
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub(crate) struct Paired {
    decode_cpu_ms: f64,
    bytes: u64,
}

impl Floor {
    /// Measures the floor of the chunks `levels` recorded decoding
    /// (`ChunkCache::record_keys`).
    pub fn measure(ctx: &Arc<vellum_gpu::Context>, levels: &BrickLevels) -> Result<Self> {
        let keys = levels.chunks().recorded_keys();
        let (decode_s, decode_cpu_ms, bytes) = levels.plain_decode(&keys)?;
        let paired = levels.chunks().stats();
        Ok(Floor {
            chunks: keys.len(),
            bytes,
            decode_ms: decode_s * 1e3,
            decode_cpu_ms,
            upload_ms: upload_seconds(ctx, bytes)? * 1e3,
            paired: (paired.paired_bytes > 0).then_some(Paired {
                decode_cpu_ms: paired.paired_cpu_ms,
                bytes: paired.paired_bytes,
            }),
        })
    }
}

/// Seconds to copy `bytes` from host-visible to device-local memory, 64 MiB at a time, in one
/// submission.
fn upload_seconds(ctx: &Arc<vellum_gpu::Context>, bytes: u64) -> Result<f64> {
    use vellum_gpu::{Buffer, BufferDesc};
    let block = bytes.clamp(4, 64 << 20);
    let host = Buffer::new(ctx, "floor staging", &BufferDesc::staging(block))?;
    let device = Buffer::new(ctx, "floor device", &BufferDesc::storage(block))?;
    let start = std::time::Instant::now();
    vellum_gpu::submit_once(ctx, "upload floor", |f| {
        for i in 0..bytes.div_ceil(block) {
            if i > 0 {
                use vellum_gpu::Access::TransferWrite;
                vellum_gpu::commands::memory_transition(ctx, f.cmd, TransferWrite, TransferWrite);
            }
            vellum_gpu::commands::copy_buffer(ctx, f.cmd, &host, &device, block);
        }
        Ok(())
    })?;
    Ok(start.elapsed().as_secs_f64())
}
