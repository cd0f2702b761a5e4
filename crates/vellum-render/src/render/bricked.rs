//! Rendering a volume through the brick cache (issues 26 and 39): the still frame, which waits
//! until the frame is complete at the levels its pixels ask for, so that the image is
//! deterministic.
//!
//! A frame runs in passes. Each pass continues every ray from where the last one stopped it
//! (its colours, depth and next sample are saved per pixel) up to the first brick it needs and
//! the cache does not hold, and asks for that brick. A pass after the first runs only the tiles
//! of 8 × 8 rays with a ray that an arrived brick lets go on (`ray_wake.comp` lists them; the
//! others would stop where they stopped, and only ask for their bricks again). The streamer's loaders read the bricks
//! asked for, nearest the eye first, while the GPU runs the pass; the next pass uploads what has
//! arrived (into free slots, or in place of the least recently used ones; the coarsest level
//! stays) and goes on. Host and GPU work at once: the loaders never wait for a pass, and a pass
//! waits only for the first bricks of its batch. Every pass loads at least one brick some ray
//! waits for and that ray then moves on, so the frame completes whatever the budget, as long as
//! it holds the coarsest level and one brick. With a bound on the wait, a last pass finishes
//! every ray with what is resident, falling back to coarser levels where a brick is missing.
//! When the frame's bricks all fit the pool, the frame returned is drawn once more from scratch
//! over them, so that its `raycast` time is a whole frame's.
//!
//! A progressive frame (no waiting, coarser levels where a brick is missing) is drawn once the
//! coarsest level is resident when the caller asks for it (`StillOptions::first_frame`), and
//! then after every pass when it asks for refinements (`StillOptions::progress`).
//!
//! The samples, their order and the compositing are the in-core ray caster's, so the complete
//! frame equals the in-core frame of the same levels.

use crate::classify::textures::GpuClassification;
use crate::passes::paging::{PagedVolume, MODE_RESUME, MODE_WAIT};
use crate::render::frame::Renderer;
use crate::render::stream::{record_arrivals, Arrived, Order, Streamer};
use crate::render::targets::{FrameImage, FrameTargets, TargetsReadback};
use crate::render::view::View;
use std::time::{Duration, Instant};
use vellum_error::{Error, Result};
use vellum_gpu::{Frames, FramesDesc};

/// `--gpu-budget` (MiB) in bytes, or half the device's largest memory heap: what a volume's
/// textures may take before it goes through the brick cache.
pub fn gpu_budget_bytes(ctx: &vellum_gpu::Context, mib: Option<f64>) -> Result<u64> {
    match mib {
        None => Ok(ctx.info.device_local_heap_bytes / 2),
        Some(m) => gpu_budget_bytes_of(m),
    }
}

/// A `--gpu-budget` of `mib` MiB in bytes, which needs no device.
pub fn gpu_budget_bytes_of(mib: f64) -> Result<u64> {
    match mib {
        m if m.is_finite() && m > 0.0 => Ok((m * (1u64 << 20) as f64) as u64),
        m => Err(Error::Invalid(format!(
            "`gpu_budget` {m} is invalid; expected a positive number of MiB"
        ))),
    }
}

/// Bricks uploaded between two passes at most.
pub(crate) const LOADS_PER_PASS: usize = 2048;

/// The next pass waits for this share of the bricks the rays asked for (within what the pool
/// can take): a pass then runs on the GPU while the loaders read the rest. On the 2048³ frame at
/// 256² on lavapipe (two rounds each), an eighth took 1,204–1,262 ms, with the loaders and the
/// GPU both busy for 58–61 % of it; a quarter 1,267–1,296 ms (49–50 %), a half 1,334–1,369 ms,
/// a sixteenth 1,236–1,258 ms. Through 3.5 MiB, the 512³ frame loads 1.026 bricks per brick
/// touched at an eighth, 1.028 at a quarter.
const BATCH_SHARE: usize = 8;

/// What streaming one frame did.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct StreamReport {
    /// Ray-casting passes, the last one included.
    pub passes: usize,
    /// Bricks placed in the cache (uploaded, or sharing the slot of their constant value).
    pub bricks_loaded: u64,
    /// Distinct bricks the frame's rays asked for: what it touched and did not hold.
    pub bricks_touched: u64,
    /// Bricks loaded per brick touched (1 when nothing was read twice).
    pub(crate) loads_per_touched: f64,
    /// Bricks loaded per level, finest first.
    pub loaded_per_level: Vec<u64>,
    /// Of the bricks loaded, those of one value that shared a slot and uploaded nothing.
    pub bricks_shared: u64,
    /// Bricks evicted during the frame to make room for others (the least recently used).
    pub bricks_evicted: u64,
    /// Bytes uploaded into the pool (each brick's voxels with a border, at 8 or 16 bits).
    pub bytes_streamed: u64,
    /// Chunks of the store decoded, their bytes of voxels, and those bytes per second of the frame.
    pub chunks_decoded: u64,
    /// Bytes of voxels those chunks decoded to.
    pub(crate) source_bytes: u64,
    /// `source_bytes` in MiB per second of the whole frame (`total_ms`).
    pub source_mib_per_s: f64,
    /// Milliseconds the loaders spent decoding chunks and keeping them, summed over the loaders.
    pub(crate) decode_ms: f64,
    /// The CPU time of that decoding, summed over the loaders: `decode_ms` less the time they
    /// waited for a core (on lavapipe, the GPU's work shares the cores) and the time they kept
    /// the chunks (`keep_cpu_ms`).
    pub(crate) decode_cpu_ms: f64,
    /// The CPU time the loaders spent keeping the decoded chunks: finding whether each holds
    /// one value, converting it to 16 bits into the chunk cache's memory (an 8-bit store's:
    /// copying it), and for a chunk of one value, whether it is still in the store.
    pub(crate) keep_cpu_ms: f64,
    /// Milliseconds the loaders were reading (at least one of them), the GPU was busy, and both
    /// at once; the share of the frame during which both were busy.
    pub host_ms: f64,
    /// Milliseconds the GPU was busy with the frame's passes.
    pub gpu_ms: f64,
    /// Milliseconds during which the loaders and the GPU were both busy.
    pub(crate) both_ms: f64,
    /// `both_ms` over `total_ms`, in [0, 1].
    pub both_share: f64,
    /// Per pass: GPU ms.
    pub(crate) pass_gpu_ms: Vec<f64>,
    /// Per pass: ms the loaders were reading (at least one of them) from the end of the pass
    /// before (the frame's start for the first) to the end of this one.
    pub(crate) pass_host_ms: Vec<f64>,
    /// Per pass: bricks uploaded before it (none before the last frame).
    pub(crate) pass_bricks: Vec<usize>,
    /// Whether every ray reached its end with the bricks it asked for (false: the wait was cut
    /// short and missing bricks were sampled from coarser levels).
    pub complete: bool,
    /// Whether the last frame drew every ray from its start over resident bricks (asked for,
    /// [`StillOptions::time_whole_frame`], and the frame's bricks all fit the pool), so that
    /// its `raycast` time is a whole frame's.
    pub whole_frame: bool,
    /// Slots in the pool, and bricks resident at the end.
    pub capacity: usize,
    /// Bricks resident in the pool at the end of the frame.
    pub resident: usize,
    /// Bytes of the pool images.
    pub pool_bytes: u64,
    /// Milliseconds until the first pass had run, until the first (coarse) frame was drawn,
    /// and until the complete frame was.
    pub(crate) first_pass_ms: f64,
    /// Milliseconds until the first (coarse) frame was drawn; none when no one asked for it
    /// ([`StillOptions::first_frame`], [`StillOptions::progress`]).
    pub first_frame_ms: Option<f64>,
    /// Milliseconds until the complete frame was drawn: the whole frame's time.
    pub total_ms: f64,
    /// Refinements drawn on the way (progressive frames).
    pub progress_frames: usize,
    /// Where the main thread's time between the first pass and the last went.
    pub main: MainThread,
    /// The floor measured after the frame when asked (`render::stream::Floor`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub floor: Option<crate::render::stream::Floor>,
}

/// The main thread's milliseconds over a still frame's passes, summed: what the passes leave
/// between the GPU's work and the loaders', for reading a frame's time against its floor.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct MainThread {
    /// Recording and submitting the passes: the bricks that arrived staged, the page table's
    /// words, the commands.
    pub record_ms: f64,
    /// Waiting for the passes to finish on the GPU.
    pub gpu_wait_ms: f64,
    /// Reading what the rays asked for and asking the loaders for it.
    pub feedback_ms: f64,
    /// Waiting for the next batch of bricks from the loaders, and placing it in the cache.
    pub batch_ms: f64,
}

/// What a still frame may do besides waiting for its bricks.
#[derive(Default)]
pub struct StillOptions<'a> {
    /// Finish with what is resident after this long.
    pub max_wait: Option<Duration>,
    /// Called with every progressive frame (the first coarse one, then one after each pass).
    #[allow(clippy::type_complexity)]
    pub progress: Option<&'a mut dyn FnMut(&FrameImage) -> Result<()>>,
    /// Draws the first coarse frame, and times it, though `progress` is not there to take it.
    /// Without either, none is drawn: it would cost a whole frame's ray casting before the
    /// first pass (a quarter of a second at 512² on lavapipe) for nothing.
    pub first_frame: bool,
    /// When the frame's bricks all fit (none was evicted), draws the last frame whole over them,
    /// every ray from its start, so that its `raycast` is timed as one frame's (`bench scale`
    /// and the device bench compare it with the in-core frame). Without it the last frame keeps
    /// the rays the passes finished, which is the same picture (two runs differ as much), and
    /// a still frame does not pay a whole ray cast at its end with nothing left to load: on the
    /// 2048³ frame at 256² on lavapipe, 74 ms of GPU time when nothing else ran.
    pub time_whole_frame: bool,
}

/// The state of one still frame between its passes.
struct Still<'a> {
    ctx: std::sync::Arc<vellum_gpu::Context>,
    targets: FrameTargets,
    frames: Frames,
    report: StreamReport,
    start: Instant,
    /// The GPU's busy intervals (seconds since `start`).
    gpu: Vec<(f64, f64)>,
    /// When the last frame read back had finished on the GPU (seconds since `start`).
    finished: f64,
    plain: View,
    view: &'a View,
}

impl Renderer {
    /// Renders one frame of the bricked volume `vol` (see the module's documentation) with the
    /// bricks `stream` reads; the composite and layers come back to the host.
    pub fn render_bricked(
        &mut self,
        vol: &mut PagedVolume,
        classify: &mut GpuClassification,
        stream: &mut Streamer,
        view: &View,
        mut opts: StillOptions,
    ) -> Result<(FrameImage, StreamReport)> {
        let ctx = self.context().clone();
        let mut s = Still {
            targets: FrameTargets::new(&ctx),
            frames: Frames::new(&ctx, &FramesDesc::one_shot("bricked frame", 32))?,
            report: StreamReport {
                loaded_per_level: vec![0; vol.paged.levels.levels().len()],
                ..StreamReport::default()
            },
            start: Instant::now(),
            gpu: Vec::new(),
            finished: 0.0,
            // The passes draw no style; the last frame draws it over the finished rays.
            plain: View {
                style: None,
                ..view.clone()
            },
            view,
            ctx,
        };
        let (loaded_before, evicted_before, shared_before) = (
            vol.paged.cache.loaded,
            vol.paged.cache.evicted,
            vol.paged.cache.shared_loads,
        );
        let chunks_before = vol.paged.levels.chunks().stats();
        let per_level_before = stream.per_level.clone();
        stream.asked.clear();
        stream.start(&vol.paged);
        self.first_frame(&mut s, vol, classify, stream, &mut opts)?;
        let mut mode = MODE_WAIT;
        let mut arrived = Vec::new();
        loop {
            s.report.pass_bricks.push(arrived.len());
            vol.paged.mode = mode;
            self.pass(&mut s, vol, classify, &arrived)?;
            if s.report.passes == 1 {
                s.report.first_pass_ms = s.start.elapsed().as_secs_f64() * 1e3;
            }
            mode |= MODE_RESUME;
            let asking = Instant::now();
            let wanted = vol.paged.take_feedback()?.wanted;
            if wanted.is_empty() {
                s.report.complete = true;
                break;
            }
            stream.request(&vol.paged, &s.plain, &wanted, Order::FrontToBack);
            s.report.main.feedback_ms += asking.elapsed().as_secs_f64() * 1e3;
            if let Some(progress) = opts.progress.as_deref_mut() {
                let image = self.progressive(&mut s, vol, classify)?;
                progress(&image)?;
                vol.paged.mode = mode;
            }
            let left = opts.max_wait.map(|w| w.saturating_sub(s.start.elapsed()));
            if left.is_some_and(|l| l.is_zero()) {
                break;
            }
            let batching = Instant::now();
            let batch = self.next_batch(vol, stream, wanted.len(), left)?;
            s.report.main.batch_ms += batching.elapsed().as_secs_f64() * 1e3;
            if batch.placed == 0 && stream.outstanding() == 0 {
                // Nothing asked can be read (every brick asked for is resident already, or
                // known to hold nothing): finish with what is resident rather than spin.
                break;
            }
            arrived = batch.uploads;
        }
        let whole = opts.time_whole_frame;
        let image = self.last_frame(&mut s, vol, classify, (evicted_before, whole))?;
        let r = &mut s.report;
        let c = &vol.paged.cache;
        r.bricks_loaded = c.loaded - loaded_before;
        r.bricks_shared = c.shared_loads - shared_before;
        r.bricks_evicted = c.evicted - evicted_before;
        r.bricks_touched = stream.asked.len() as u64;
        r.loads_per_touched = r.bricks_loaded as f64 / r.bricks_touched.max(1) as f64;
        for (l, n) in stream.per_level.iter().enumerate() {
            if let Some(r) = r.loaded_per_level.get_mut(l) {
                *r = n - per_level_before.get(l).copied().unwrap_or(0);
            }
        }
        r.capacity = c.capacity();
        r.resident = c.resident();
        r.pool_bytes = vol.paged.pool_bytes;
        r.bytes_streamed = stream.uploaded_bytes;
        let chunks = vol.paged.levels.chunks().stats();
        r.chunks_decoded = chunks.decoded - chunks_before.decoded;
        r.source_bytes = chunks.decoded_bytes - chunks_before.decoded_bytes;
        r.decode_ms = chunks.decode_ms - chunks_before.decode_ms;
        r.decode_cpu_ms = chunks.decode_cpu_ms - chunks_before.decode_cpu_ms;
        r.keep_cpu_ms = chunks.keep_cpu_ms - chunks_before.keep_cpu_ms;
        r.total_ms = s.start.elapsed().as_secs_f64() * 1e3;
        r.source_mib_per_s =
            r.source_bytes as f64 / (1 << 20) as f64 / (r.total_ms / 1e3).max(1e-9);
        let host = stream.loader().timeline(s.start);
        r.host_ms = host.iter().map(|(a, b)| b - a).sum::<f64>() * 1e3;
        r.gpu_ms = s.gpu.iter().map(|(a, b)| b - a).sum::<f64>() * 1e3;
        r.both_ms = vellum_volume::stream::overlap(&host, &s.gpu) * 1e3;
        let ends = s.gpu.iter().map(|&(_, b)| b);
        let windows = std::iter::once(0.0).chain(ends.clone()).zip(ends);
        r.pass_host_ms = windows
            .map(|w| vellum_volume::stream::overlap(&host, &[w]) * 1e3)
            .collect();
        r.both_share = r.both_ms / r.total_ms.max(1e-9);
        Ok((image, s.report))
    }

    /// The first bricks: the coarsest level, read before anything else, and the first
    /// progressive frame over it when it is asked for.
    fn first_frame(
        &mut self,
        s: &mut Still,
        vol: &mut PagedVolume,
        classify: &mut GpuClassification,
        stream: &mut Streamer,
        opts: &mut StillOptions,
    ) -> Result<()> {
        let pinned = vellum_volume::bricks::BrickCache::pinned_entries(&vol.paged.levels).len();
        let mut arrived = Vec::new();
        while stream.outstanding() > 0 {
            let batch = stream.arrivals(
                &mut vol.paged,
                pinned,
                Some((pinned, Duration::from_secs(3600))),
                true,
            )?;
            arrived.extend(batch.uploads);
        }
        let ctx = s.ctx.clone();
        s.frames
            .frame(|f| record_arrivals(vol, &ctx, f, &arrived))?;
        s.frames.wait_idle()?;
        if !opts.first_frame && opts.progress.is_none() {
            return Ok(());
        }
        let image = self.progressive(s, vol, classify)?;
        s.report.first_frame_ms = Some(s.start.elapsed().as_secs_f64() * 1e3);
        if let Some(progress) = opts.progress.as_deref_mut() {
            progress(&image)?;
        }
        Ok(())
    }

    /// The bricks for the next pass: those ready, waiting until a batch is ([`BATCH_SHARE`] of
    /// what the rays asked for, within what the pool can take) or `left` runs out.
    fn next_batch(
        &mut self,
        vol: &mut PagedVolume,
        stream: &mut Streamer,
        asked: usize,
        left: Option<Duration>,
    ) -> Result<crate::render::stream::Batch> {
        let c = &vol.paged.cache;
        let room = (c.capacity() - vellum_volume::bricks::min_slots(&vol.paged.levels) + 1).max(1);
        // The free slots, and at most half of those that must be evicted: a batch that evicted
        // the whole pool would evict the bricks the last batch brought for rays that have not
        // reached them yet (512³ through 16 MiB: 1.04-1.05 loads per brick touched, against
        // 1.02 so).
        let free = c.free_slots().min(room);
        let max = (free + (room - free).div_ceil(2)).min(LOADS_PER_PASS);
        let min = asked.div_ceil(BATCH_SHARE).clamp(1, max);
        let wait = left.unwrap_or(Duration::from_secs(3600));
        stream.arrivals(&mut vol.paged, max, Some((min, wait)), true)
    }

    /// One pass: `arrived` uploaded, then the rays cast without the style, timed.
    fn pass(
        &mut self,
        s: &mut Still,
        vol: &PagedVolume,
        classify: &mut GpuClassification,
        arrived: &[Arrived],
    ) -> Result<()> {
        let ctx = s.ctx.clone();
        let view = &s.plain;
        let targets = &mut s.targets;
        let recording = Instant::now();
        s.frames.frame(|f| {
            record_arrivals(vol, &ctx, f, arrived)?;
            self.record(f, vol, classify, view, targets).map(|_| ())
        })?;
        let waiting = Instant::now();
        s.frames.wait_idle()?;
        s.report.main.record_ms += (waiting - recording).as_secs_f64() * 1e3;
        s.report.main.gpu_wait_ms += waiting.elapsed().as_secs_f64() * 1e3;
        let done = s.start.elapsed().as_secs_f64();
        let ms: f64 = s
            .frames
            .take_finished()
            .iter()
            .flat_map(|r| r.passes.iter().map(|p| p.ms))
            .sum();
        s.gpu.push(((done - ms / 1e3).max(0.0), done));
        s.report.pass_gpu_ms.push(ms);
        s.report.passes += 1;
        Ok(())
    }

    /// A progressive frame: every ray from its start with what is resident, coarser levels
    /// where a brick is missing, read back. The frame's passes keep their saved rays.
    fn progressive(
        &mut self,
        s: &mut Still,
        vol: &mut PagedVolume,
        classify: &mut GpuClassification,
    ) -> Result<FrameImage> {
        let mode = std::mem::replace(&mut vol.paged.mode, 0);
        let image = self.read_frame(s, vol, classify);
        vol.paged.mode = mode;
        s.report.progress_frames += 1;
        image
    }

    /// A frame of the view (with its style) in the volume's mode, read back.
    fn read_frame(
        &mut self,
        s: &mut Still,
        vol: &PagedVolume,
        classify: &mut GpuClassification,
    ) -> Result<FrameImage> {
        let ctx = s.ctx.clone();
        let view = s.view;
        let targets = &mut s.targets;
        let ((recorded, readback), _) = s.frames.frame(|f| {
            let r = self.record(f, vol, classify, view, targets)?;
            let rb = TargetsReadback::new(&ctx, targets)?;
            rb.record(f, targets);
            Ok((r, rb))
        })?;
        let passes = s.frames.finish()?;
        s.finished = s.start.elapsed().as_secs_f64();
        Ok(recorded.image(view.size, readback.read()?, passes, None))
    }

    /// The last frame, with the style and the readback. When `whole` is asked and the frame's
    /// bricks all fit (none was evicted since `evicted_before`), every ray is drawn from its
    /// start again over them: the frame the passes built, drawn as the viewer draws it and
    /// timed as one. Otherwise the rays' saved results are kept (or, cut short, each ray goes
    /// on with what is resident).
    fn last_frame(
        &mut self,
        s: &mut Still,
        vol: &mut PagedVolume,
        classify: &mut GpuClassification,
        (evicted_before, whole): (u64, bool),
    ) -> Result<FrameImage> {
        let evicted = vol.paged.cache.evicted - evicted_before;
        s.report.whole_frame = whole && s.report.complete && evicted == 0;
        vol.paged.mode = if s.report.whole_frame { 0 } else { MODE_RESUME };
        let image = self.read_frame(s, vol, classify);
        vol.paged.mode = 0;
        let image = image?;
        // Its GPU time (the ray cast, the style's passes and the readback) as the last pass's,
        // ending when the frame's work was waited for.
        let done = s.finished;
        let ms: f64 = image.passes.iter().map(|p| p.ms).sum();
        s.gpu.push(((done - ms / 1e3).max(0.0), done));
        s.report.pass_gpu_ms.push(ms);
        s.report.pass_bricks.push(0);
        s.report.passes += 1;
        Ok(image)
    }
}
