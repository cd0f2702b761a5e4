//! The GPU side of the brick cache (issue 26): the pool images, the feedback buffer, and the
//! uploads of bricks into their slots. Which brick goes where is decided on the host
//! (`volume::bricks`); the ray caster reads the page table, staged with each frame, and writes
//! what it missed into the feedback buffer.
//!
//! ## Page table (what `raycast.comp` reads, one u32 array staged per frame)
//! - words 0..8: levels, brick edge, slot edge, mode (bit 0: rays stop at a missing brick and
//!   wait for it, bit 1: rays continue from the state the previous pass saved), pool slots along
//!   x and y, and the level-of-detail line (a, b as f32 bits: a sample at distance d from the eye
//!   covers a·d + b level-0 voxels; its level is ⌊log2⌋ of that, clamped);
//! - words 8 + 8·l ..: per level l, its first entry, its bricks along x, y, z, its texture to
//!   voxel scale along x, y, z, and level 0's voxel over its own (f32 bits): opacity is corrected
//!   per voxel of the level sampled, so that a coarse level looks as that level rendered in core;

//! - from word [`HEADER`]: per entry, its slot + 1, or 0 when not resident.

use crate::error::{Error, Result};
use crate::gpu::resources::BufferLocation;
use crate::gpu::{Access, Buffer, BufferDesc, Context, Frame, Image, ImageDesc};
use crate::passes::normals::{Bricks, VolumeTextures};
use crate::volume::bricks::{BrickCache, BrickLevels, BrickTexels, MAX_LEVELS, SLOT, SLOT_BYTES};
use ash::vk;
use std::sync::Arc;

/// Words before the first page-table entry.
pub const HEADER: usize = 8 + 8 * MAX_LEVELS;
/// Mode bit: rays stop at a missing brick (and ask for it) instead of sampling a coarser level.
pub const MODE_WAIT: u32 = 1;
/// Mode bit: rays continue from the state the previous pass of this frame saved.
pub const MODE_RESUME: u32 = 2;
/// Feedback flag: a resident brick was read (`USED_BIT` in raycast.comp); the bits below count
/// the rays that asked for a missing one.
pub const USED_BIT: u32 = 1 << 31;

/// What a frame's rays said about the bricks ([`Paged::take_feedback`]).
#[derive(Clone, Debug, Default)]
pub struct Feedback {
    /// Missing bricks asked for, with how many rays asked.
    pub wanted: Vec<(usize, u32)>,
    /// Resident bricks read (frames that do not wait only).
    pub used: Vec<usize>,
}

/// Bytes of one ray's saved state (`RayState` in raycast.comp).
pub const RAY_STATE_BYTES: u64 = 80;

/// A volume in the brick cache.
pub struct Paged {
    pub levels: Arc<BrickLevels>,
    pub cache: BrickCache,
    /// Slots along x, y, z of the pool images.
    pub grid: [usize; 3],
    /// Per page-table entry, how many rays asked for the brick in the last frame; the host reads
    /// it once the frame has completed.
    pub feedback: Buffer,
    /// Page-table mode bits for the next frame ([`MODE_WAIT`], [`MODE_RESUME`]).
    pub mode: u32,
    /// Sample level 0 everywhere instead of choosing the level by projected voxel size.
    pub finest: bool,
    /// Bytes the pool images take.
    pub pool_bytes: u64,
    /// Each ray keeps its last brick's place in the pool and reuses it while its samples stay in
    /// that brick (the ray caster's `BRICK_REUSE` variant). On by default on a GPU, where it
    /// halves the bricked frame (H100, BENCHMARKS.md); off on lavapipe, whose lanes run both
    /// sides of the test and come out slower. `VELLUM_BRICK_REUSE=0|1` overrides, for measuring.
    pub reuse: bool,
    /// Each ray keeps the stretch of its path over which its last lookup holds (the brick, and
    /// the level its distance from the eye wants) and places the samples there by one
    /// multiply-add, without choosing a level or finding a brick (the ray caster's `BRICK_SPAN`
    /// variant). Off by default until a GPU has measured it; `VELLUM_BRICK_SPAN=0|1` overrides.
    pub span: bool,
}

/// The default of [`Paged::reuse`] on a device of `device_type`.
pub fn brick_reuse(device_type: &str) -> bool {
    match std::env::var("VELLUM_BRICK_REUSE").ok().as_deref() {
        Some("0") => false,
        Some("1") => true,
        _ => device_type != "CPU",
    }
}

/// The default of [`Paged::span`].
pub fn brick_span() -> bool {
    std::env::var("VELLUM_BRICK_SPAN").ok().as_deref() == Some("1")
}

/// Slots per axis for a pool of at most `capacity` slots, each axis within `max_texels`.
pub fn pool_grid(capacity: usize, max_texels: usize) -> [usize; 3] {
    let m = (max_texels / SLOT).max(1);
    // The largest g with g^k <= n.
    let root = |n: usize, k: u32| (1..=n).take_while(|g| g.pow(k) <= n).last().unwrap_or(1);
    let gx = root(capacity, 3).clamp(1, m);
    let gy = root(capacity / gx, 2).clamp(1, m);
    let gz = (capacity / (gx * gy)).clamp(1, m);
    [gx, gy, gz]
}

impl VolumeTextures {
    /// A volume for the brick cache: pool images of as many slots as `budget_bytes` holds (the
    /// intensity and gradient textures are the pools), nothing resident yet. `finest` samples
    /// level 0 everywhere.
    pub fn paged(
        ctx: &Arc<Context>,
        levels: BrickLevels,
        budget_bytes: u64,
        finest: bool,
    ) -> Result<Self> {
        let max = ctx.info.max_image_dimension_3d as usize;
        let grid = pool_grid((budget_bytes / SLOT_BYTES as u64) as usize, max);
        let capacity = grid
            .iter()
            .product::<usize>()
            .min((budget_bytes / SLOT_BYTES as u64) as usize);
        let mib = budget_bytes as f64 / (1 << 20) as f64;
        let cache = BrickCache::new(&levels, capacity, mib)?;
        let extent = grid.map(|g| (g * SLOT) as u32);
        let image = |name: &str, format| Image::new(ctx, name, &ImageDesc::new_3d(format, extent));
        let intensity = image("brick pool intensity", vk::Format::R16_UNORM)?;
        let gradient = image("brick pool gradient", vk::Format::R16G16B16A16_SFLOAT)?;
        let feedback = Buffer::new(
            ctx,
            "brick feedback",
            &BufferDesc {
                size: (levels.entries().max(1) * 4) as u64,
                usage: vk::BufferUsageFlags::STORAGE_BUFFER | vk::BufferUsageFlags::TRANSFER_DST,
                location: BufferLocation::Readback,
            },
        )?;
        let level0 = levels.levels()[0].clone();
        Ok(VolumeTextures {
            intensity,
            gradient,
            range: levels.range,
            dims: level0.dims,
            spacing: level0.spacing,
            geometry: levels.geometry,
            occlusion: None,
            // One brick of the full range: empty-space skipping is off on this path.
            bricks: Bricks {
                counts: [1; 3],
                range: vec![[0, u16::MAX]],
            },
            importance: None,
            id: crate::passes::normals::next_volume_id(),
            // Lines are not drawn through the brick cache.
            auto_line_smooth: 0,
            paged: Some(Box::new(Paged {
                levels: Arc::new(levels),
                cache,
                grid,
                feedback,
                mode: 0,
                finest,
                pool_bytes: (capacity * SLOT_BYTES) as u64,
                reuse: brick_reuse(&ctx.info.device_type),
                span: brick_span(),
            })),
        })
    }
}

impl Paged {
    /// The page table's header for a frame whose samples at distance d from the eye cover
    /// `lod.0 · d + lod.1` level-0 voxels (see the module's documentation); the entries,
    /// `cache.page_table`, follow it.
    pub fn header(&self, lod: (f32, f32)) -> [u32; HEADER] {
        let levels = self.levels.levels();
        let (a, b) = if self.finest { (0.0, 0.0) } else { lod };
        let mut words = [0u32; HEADER];
        let dims0 = levels[0].dims;
        let s0 = levels[0].spacing;
        words[..8].copy_from_slice(&[
            levels.len() as u32,
            crate::volume::bricks::BRICK as u32,
            SLOT as u32,
            self.mode,
            self.grid[0] as u32,
            self.grid[1] as u32,
            a.to_bits(),
            b.to_bits(),
        ]);
        for (i, l) in levels.iter().enumerate() {
            // Texture coordinate (0..1 over level 0's box) to this level's voxel units.
            let scale: [f32; 3] =
                std::array::from_fn(|k| (dims0[k] as f64 * s0[k] / l.spacing[k]) as f32);
            let w = &mut words[8 + 8 * i..16 + 8 * i];
            w[..4].copy_from_slice(&[
                l.first as u32,
                l.counts[0] as u32,
                l.counts[1] as u32,
                l.counts[2] as u32,
            ]);
            w[4..7].copy_from_slice(&scale.map(f32::to_bits));
            // Level 0's voxel over this level's: the opacity correction's unit.
            let ratio = (0..3)
                .map(|k| s0[k] / l.spacing[k])
                .fold(f64::INFINITY, f64::min);
            w[7] = (ratio as f32).to_bits();
        }
        words
    }

    /// What the rays of the last completed frame said: the missing bricks they asked for (with
    /// how many asked) and, in a frame that does not wait, the resident ones they read.
    pub fn take_feedback(&mut self) -> Result<Feedback> {
        let counts: &[u32] = bytemuck::cast_slice(self.feedback.mapped().ok_or_else(|| {
            Error::Invalid("the brick feedback buffer is not host-visible".into())
        })?);
        let mut f = Feedback::default();
        for (e, &c) in counts.iter().enumerate() {
            if c & USED_BIT != 0 {
                f.used.push(e);
            }
            if c & !USED_BIT != 0 {
                f.wanted.push((e, c & !USED_BIT));
            }
        }
        Ok(f)
    }

    /// Records the clearing of the feedback buffer, before the frame's ray casting writes it.
    pub fn record_clear_feedback(&self, ctx: &Context, frame: &mut Frame) {
        crate::gpu::commands::memory_transition(
            ctx,
            frame.cmd,
            Access::HostRead,
            Access::TransferWrite,
        );
        unsafe {
            ctx.device
                .cmd_fill_buffer(frame.cmd, self.feedback.raw, 0, vk::WHOLE_SIZE, 0)
        };
        crate::gpu::commands::memory_transition(
            ctx,
            frame.cmd,
            Access::TransferWrite,
            Access::ComputeReadWrite,
        );
    }

    /// Records the copies of `loads` (slot, texels) into the pool images through the frame's
    /// staging ring; the images end ready for sampling in compute.
    pub fn record_loads(
        &self,
        ctx: &Context,
        frame: &mut Frame,
        pools: [&Image; 2],
        loads: &[(usize, BrickTexels)],
    ) -> Result<()> {
        if loads.is_empty() {
            return Ok(());
        }
        let mut copies: [Vec<(vk::Buffer, vk::BufferImageCopy)>; 2] = [Vec::new(), Vec::new()];
        for (slot, texels) in loads {
            let g = self.grid;
            let at = [slot % g[0], (slot / g[0]) % g[1], slot / (g[0] * g[1])]
                .map(|v| (v * SLOT) as i32);
            let bytes: [&[u8]; 2] = [
                bytemuck::cast_slice(&texels.intensity),
                bytemuck::cast_slice(&texels.gradient),
            ];
            for (k, b) in bytes.iter().enumerate() {
                let src = frame.staging.push(b, 16)?;
                copies[k].push((src.raw, slot_copy(src.offset, at, pools[k].aspect())));
            }
        }
        for (k, pool) in pools.iter().enumerate() {
            ctx.count_transfer(
                &pool.name,
                true,
                (copies[k].len() * SLOT.pow(3) * [2, 8][k]) as u64,
            );
            pool.transition(frame.cmd, Access::TransferWrite);
            for (raw, copy) in &copies[k] {
                unsafe {
                    ctx.device.cmd_copy_buffer_to_image(
                        frame.cmd,
                        *raw,
                        pool.raw,
                        vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                        std::slice::from_ref(copy),
                    )
                };
            }
            pool.transition(frame.cmd, Access::ComputeSampled);
        }
        Ok(())
    }
}

/// A copy of one slot's texels at `offset` in a buffer to texel `at` of a pool image.
fn slot_copy(offset: u64, at: [i32; 3], aspect: vk::ImageAspectFlags) -> vk::BufferImageCopy {
    vk::BufferImageCopy::default()
        .buffer_offset(offset)
        .image_subresource(vk::ImageSubresourceLayers {
            aspect_mask: aspect,
            mip_level: 0,
            base_array_layer: 0,
            layer_count: 1,
        })
        .image_offset(vk::Offset3D {
            x: at[0],
            y: at[1],
            z: at[2],
        })
        .image_extent(vk::Extent3D {
            width: SLOT as u32,
            height: SLOT as u32,
            depth: SLOT as u32,
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pool_grids_stay_within_the_budget_and_the_device() {
        assert_eq!(pool_grid(5, 2048), [1, 2, 2]);
        for capacity in [2usize, 7, 64, 1000, 1331, 52_000] {
            let g = pool_grid(capacity, 2048);
            let n: usize = g.iter().product();
            assert!(n <= capacity && n * 2 > capacity, "{capacity}: {g:?}");
            assert!(g.iter().all(|&s| s * SLOT <= 2048));
        }
    }
}
