//! Rendering a volume through the brick cache (issue 26): the one-shot form, which waits until
//! the frame is complete at the levels its pixels ask for, so that the image is deterministic.
//!
//! A frame runs in passes. Each pass continues every ray from where the last one stopped it
//! (its colours, depth and next sample are saved per pixel) up to the first brick it needs and
//! the cache does not hold, and asks for that brick. Between passes the host loads the bricks
//! most asked for into free slots, or in place of the least recently loaded ones (the coarsest
//! level stays). Every pass loads at least one brick some ray waits for and that ray then moves
//! on, so the frame completes whatever the budget, as long as it holds the coarsest level and
//! one brick. With a bound on the wait, a last pass finishes every ray with what is resident,
//! falling back to coarser levels where a brick is missing. When the frame's bricks all fit the
//! pool, the frame returned is drawn once more from scratch over them, so that its `raycast`
//! time is a whole frame's.
//!
//! The samples, their order and the compositing are the in-core ray caster's, so the complete
//! frame equals the in-core frame of the same levels.

use crate::classify::textures::GpuClassification;
use crate::error::{Error, Result};
use crate::gpu::{Frames, FramesDesc};
use crate::passes::normals::VolumeTextures;
use crate::passes::paging::{Paged, MODE_RESUME, MODE_WAIT};
use crate::render::frame::Renderer;
use crate::render::targets::{FrameImage, FrameTargets, TargetsReadback};
use crate::render::view::View;
use crate::volume::bricks::{BrickCache, BrickTexels};
use std::time::{Duration, Instant};

/// `--gpu-budget` (MiB) in bytes, or half the device's largest memory heap: what a volume's
/// textures may take before it goes through the brick cache.
pub fn gpu_budget_bytes(ctx: &crate::gpu::Context, mib: Option<f64>) -> Result<u64> {
    match mib {
        None => Ok(ctx.info.device_local_heap_bytes / 2),
        Some(m) if m.is_finite() && m > 0.0 => Ok((m * (1u64 << 20) as f64) as u64),
        Some(m) => Err(Error::Invalid(format!(
            "`gpu_budget` {m} is invalid; expected a positive number of MiB"
        ))),
    }
}

/// Bricks loaded between two passes at most (each is 386 KiB of staging).
pub const LOADS_PER_PASS: usize = 128;

/// What streaming one frame did.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct StreamReport {
    /// Ray-casting passes, the last one included.
    pub passes: usize,
    pub bricks_loaded: u64,
    /// Bricks loaded per level, finest first.
    pub loaded_per_level: Vec<u64>,
    pub bricks_evicted: u64,
    /// Bytes uploaded into the pool (texels with aprons and gradients).
    pub bytes_streamed: u64,
    /// Whether every ray reached its end with the bricks it asked for (false: the wait was cut
    /// short and missing bricks were sampled from coarser levels).
    pub complete: bool,
    /// Whether the last frame drew every ray from its start over resident bricks (the frame's
    /// bricks all fit the pool), so that its `raycast` time is a whole frame's.
    pub whole_frame: bool,
    /// Slots in the pool, and bricks resident at the end.
    pub capacity: usize,
    pub resident: usize,
    /// Bytes of the pool images.
    pub pool_bytes: u64,
    /// Milliseconds until the first pass had run, and in all.
    pub first_pass_ms: f64,
    pub total_ms: f64,
}

impl Renderer {
    /// Renders one frame of the bricked volume `vol` (see the module's documentation), waiting
    /// at most `max_wait` for its bricks; the composite and layers come back to the host.
    pub fn render_bricked(
        &mut self,
        vol: &mut VolumeTextures,
        classify: &mut GpuClassification,
        view: &View,
        max_wait: Option<Duration>,
    ) -> Result<(FrameImage, StreamReport)> {
        let start = Instant::now();
        let ctx = self.context().clone();
        let mut targets = FrameTargets::new(&ctx);
        let mut frames = Frames::new(&ctx, &FramesDesc::one_shot("bricked frame", 32))?;
        let mut report = StreamReport {
            loaded_per_level: vec![0; paged(vol)?.levels.levels().len()],
            ..StreamReport::default()
        };
        // The passes draw no style; the last frame draws it over the finished rays.
        let plain = View {
            style: None,
            ..view.clone()
        };
        let pinned = BrickCache::pinned_entries(&paged(vol)?.levels);
        let evicted_before = paged(vol)?.cache.evicted;
        let mut loads = plan_loads(
            vol,
            &pinned.iter().map(|&e| (e, 1)).collect::<Vec<_>>(),
            &mut report,
        )?;
        let mut mode = MODE_WAIT;
        loop {
            report.bytes_streamed += loads.len() as u64 * crate::volume::bricks::SLOT_BYTES as u64;
            paged_mut(vol)?.mode = mode;
            frames.frame(|f| {
                let p = paged(vol)?;
                p.record_loads(&ctx, f, [&vol.intensity, &vol.gradient], &loads)?;
                self.record(f, vol, classify, &plain, &mut targets)
            })?;
            frames.wait_idle()?;
            report.passes += 1;
            if report.passes == 1 {
                report.first_pass_ms = start.elapsed().as_secs_f64() * 1e3;
            }
            mode |= MODE_RESUME;
            let wanted = paged_mut(vol)?.take_feedback()?.wanted;
            if wanted.is_empty() {
                report.complete = true;
                break;
            }
            if max_wait.is_some_and(|w| start.elapsed() >= w) {
                break;
            }
            loads = plan_loads(vol, &wanted, &mut report)?;
            if loads.is_empty() {
                // Cannot happen while the cache holds one evictable slot (see `BrickCache::plan`);
                // finish with what is resident rather than spin.
                break;
            }
        }
        // The last frame, with the style and the readback. When the frame's bricks all fit (none
        // was evicted), every ray is drawn from its start again over them: the frame the passes
        // built, drawn as the viewer draws it and timed as one. Otherwise the rays' saved results
        // are kept (or, cut short, each ray goes on with what is resident).
        let evicted = paged(vol)?.cache.evicted - evicted_before;
        report.whole_frame = report.complete && evicted == 0;
        paged_mut(vol)?.mode = if report.whole_frame { 0 } else { MODE_RESUME };
        let (recorded, readback) = frames
            .frame(|f| {
                let r = self.record(f, vol, classify, view, &mut targets)?;
                let rb = TargetsReadback::new(&ctx, &targets)?;
                rb.record(f, &targets);
                Ok((r, rb))
            })?
            .0;
        let passes = frames.finish()?;
        report.passes += 1;
        let back = readback.read()?;
        let p = paged(vol)?;
        report.bricks_loaded = p.cache.loaded;
        report.bricks_evicted = p.cache.evicted;
        report.capacity = p.cache.capacity();
        report.resident = p.cache.resident();
        report.pool_bytes = p.pool_bytes;
        report.total_ms = start.elapsed().as_secs_f64() * 1e3;
        Ok((recorded.image(view.size, back, passes, None), report))
    }
}

fn paged(vol: &VolumeTextures) -> Result<&Paged> {
    vol.paged
        .as_deref()
        .ok_or_else(|| Error::Invalid("the volume is not in the brick cache".into()))
}

fn paged_mut(vol: &mut VolumeTextures) -> Result<&mut Paged> {
    vol.paged
        .as_deref_mut()
        .ok_or_else(|| Error::Invalid("the volume is not in the brick cache".into()))
}

/// Gives slots to the `wanted` entries the cache takes now and reads their texels (in
/// parallel): (slot, texels) per brick to upload.
fn plan_loads(
    vol: &mut VolumeTextures,
    wanted: &[(usize, u32)],
    report: &mut StreamReport,
) -> Result<Vec<(usize, BrickTexels)>> {
    use rayon::prelude::*;
    let p = paged_mut(vol)?;
    let plan = p.cache.plan(wanted, LOADS_PER_PASS);
    let levels = &p.levels;
    for &(entry, _) in &plan {
        if let Some(k) = levels.key(entry) {
            report.loaded_per_level[k.level] += 1;
        }
    }
    plan.par_iter()
        .map(|&(entry, slot)| {
            let key = levels.key(entry).ok_or_else(|| {
                Error::Invalid(format!("page-table entry {entry} names no brick"))
            })?;
            Ok((slot, levels.texels(key)?))
        })
        .collect()
}
