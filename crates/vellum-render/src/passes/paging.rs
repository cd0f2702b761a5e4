//! The GPU side of the brick cache (issues 26 and 39): the pool images, the feedback buffer, and
//! the uploads of bricks into their slots. Which brick goes where is decided on the host
//! (`volume::bricks`); the ray caster reads the page table, staged with each frame, and writes
//! what it missed into the feedback buffer.
//!
//! ## Page table (what `raycast.comp` reads, staged per frame)
//! A header of `HEADER` words, bound as uniforms (the lookups read the levels' words at every
//! step, and a CPU device loads a storage buffer lane by lane but gathers uniforms), and the
//! entries, a storage buffer (a 2048³ store's are 2.4 MB).
//! - header words 0..8: levels, brick edge, slot edge, mode (bit 0: rays stop at a missing
//!   brick and wait for it, bit 1: rays continue from the state the previous pass saved), pool
//!   slots along x and y, and the level-of-detail line (a, b as f32 bits: a sample at distance d
//!   from the eye covers a·d + b level-0 voxels; its level is ⌊log2⌋ of that, clamped);
//! - header words 8 + 8·l ..: per level l, its first entry, its bricks along x, y, z, its
//!   texture to voxel scale along x, y, z, and level 0's voxel over its own (f32 bits): opacity
//!   is corrected per voxel of the level a sample wants, so that a coarse level looks as that
//!   level rendered in core (a sample drawn from a coarser level, its brick missing, keeps its
//!   own level's);
//! - the entries, two words each. The first: when the brick is resident
//!   (`RESIDENT_BIT`) its slot's place along x, y and z of the pool in bits 0-7, 8-15 and 16-23,
//!   and when the brick's range is known (`KNOWN_BIT`) what it may hold under this frame's
//!   classification (bit 24: visible context or one-pass samples, bit 25: focus), so that a ray
//!   walks past a brick that holds nothing for it, resident or not, without asking for it. When
//!   the brick is missing, bits 28-31 may name the level of the finest resident coarser brick
//!   that holds all of its samples (`HELD_SHIFT`, `volume::bricks::BrickLevels::holder`): the
//!   ray caster's walk over the coarser levels for a sample of the missing brick starts at that
//!   level, and ends there (with none named, 0, it starts at the level above). The second, read
//!   only when the range is known: the same for each of the brick's 2×2×2 sub-blocks
//!   (`volume::bricks::SUB`), bit i visible and bit 8 + i focus for sub-block i, so that a ray
//!   also walks past the empty eighths of a brick that is not all empty.
//!
//! ## Uploads
//! A brick travels as its slot's texels, at 16 bits (8 for 8-bit data): a 16-bit brick is copied
//! into its slot as it is, and `render/brick_fill.comp` writes an 8-bit one there through the
//! table that normalises it. No per-voxel arithmetic on the host but the type's conversion. The pool holds no
//! gradients; the ray caster makes each shaded sample's from the slot's intensity, whose
//! two-voxel apron holds all its Sobel operator reads (`shade.glsl`'s `sobel_at`). A slot then
//! takes 2 bytes a texel, where intensity and a gradient pool took 10: a budget holds four times
//! the bricks, and no pass makes gradients for each brick that arrives.

use crate::passes::normals::Bricks;
use std::sync::Arc;
use vellum_error::{Error, Result};
use vellum_gpu::Format;
use vellum_gpu::{
    Access, Bind, BindingKind, Buffer, BufferDesc, ComputePipeline, Context, Frame, Image,
    ImageDesc,
};
use vellum_volume::bricks::{
    BrickCache, BrickData, BrickKey, BrickLevels, BrickVoxels, MAX_LEVELS, SLOT, SLOT_BYTES,
    UNKNOWN_RANGE, UPLOAD,
};

/// What a brick may hold under a frame's classification, from its range and its mixed channels'
/// ranges (bit 0: visible context or one-pass samples, bit 1: focus).
pub(crate) type BrickFlagsOf<'a> = dyn Fn([u16; 2], &[[u16; 2]]) -> u32 + 'a;

/// Words of the page table's header (staged as uniforms; the entries are a storage buffer).
pub(crate) const HEADER: usize = 8 + 8 * MAX_LEVELS;
/// Mode bit: rays stop at a missing brick (and ask for it) instead of sampling a coarser level.
pub(crate) const MODE_WAIT: u32 = 1;
/// Mode bit: rays continue from the state the previous pass of this frame saved (with
/// [`MODE_WAIT`], only the tiles `ray_wake.comp` listed).
pub(crate) const MODE_RESUME: u32 = 2;
/// Feedback flag: a resident brick was read (`USED_BIT` in raycast.comp); a missing brick some
/// ray asked for reads 1. (Plain stores, not counts: a CPU device runs atomics lane by lane.)
pub(crate) const USED_BIT: u32 = 1 << 31;
/// Page-table word: the brick's range is known, and bits 24 and 25 say what it may hold.
pub(crate) const KNOWN_BIT: u32 = 1 << 26;
/// Page-table word: the brick is resident, its slot along x, y, z of the pool in bits 0-7, 8-15
/// and 16-23 (so that the shader finds its texels without dividing).
pub(crate) const RESIDENT_BIT: u32 = 1 << 27;
/// Page-table word of a missing brick: bits from here on hold the level of the finest resident
/// coarser brick that holds the missing one whole, so that the ray caster's walk over the
/// levels starts there and ends at its first step (0: none found; the walk starts at the level
/// above).
pub(crate) const HELD_SHIFT: u32 = 28;
/// The bits of a missing brick's word that name its holder's level.
const HELD_BITS: u32 = 0xf000_0000;

/// Whether a missing brick's holder is found again or kept from the word it had.
#[derive(Copy, Clone)]
enum Holder {
    Find,
    Keep,
}
/// Page-table sub-block word: every sub-block may hold anything.
const SUB_ALL: u32 = 0xffff;
/// Bricks one dispatch of `brick_fill` writes at most (its workgroup rows).
pub(crate) const FILL_BATCH: usize = 4096;

/// What a frame's rays said about the bricks ([`Paged::take_feedback`]).
#[derive(Clone, Debug, Default)]
pub struct Feedback {
    /// Missing bricks asked for (each with 1: the shader stores, it does not count).
    pub wanted: Vec<(usize, u32)>,
    /// Resident bricks read (frames that do not wait only).
    pub used: Vec<usize>,
}

/// Bytes of one ray's saved state (`RayState` in raycast.comp).
pub(crate) const RAY_STATE_BYTES: u64 = 80;

/// A volume in the brick cache, on the GPU: the pools (sampled as the in-core textures are), the
/// cache and the upload pass.
pub struct PagedVolume {
    /// The intensity pool: R16_UNORM, slots of [`SLOT`]³ texels.
    pub intensity: Image,
    /// Data values that map to normalised 0 and 1.
    pub range: [f64; 2],
    /// Level 0's voxels, spacing and placement.
    pub dims: [usize; 3],
    /// Level 0's physical voxel size along x, y, z.
    pub spacing: [f64; 3],
    /// Level 0's origin and directions.
    pub geometry: vellum_volume::geometry::Geometry,
    /// One brick of the full range: the in-core table of brick flags skips nothing here, since
    /// the page table carries the bricks' flags.
    pub whole: Bricks,
    /// A number no other GPU volume of the process has.
    pub id: u64,
    /// The cache's state between frames.
    pub paged: Paged,
    /// The pools of the channels mixed in the ray, when the pyramid mixes some.
    pub channels: Option<Box<ChannelPools>>,
    /// With a label volume beside the pyramid: each slot's segment indices ([`SLOT`]³ of 16
    /// bits, two a word, slot after slot), copied from each upload and read nearest by the ray
    /// caster where the in-core path reads the label volume's.
    pub labels: Option<Buffer>,
    /// `brick_fill` for an 8-bit pyramid's bricks, which it normalises through their table on
    /// the way; none for 16-bit bricks, which are copied into their slots as they are. A
    /// pyramid's levels share one voxel type, so its bricks share one width.
    fill: Option<ComputePipeline>,
}

/// The brick cache's pools of mixed channels (issue 42): RGBA16 images of the intensity pool's
/// slots, channel k in component k % 4 of pool k / 4, filled by `render/channel_fill.comp`.
pub struct ChannelPools {
    /// Channels 0-3.
    pub image: Image,
    /// Channels 4-7, with more than four.
    pub image_hi: Option<Image>,
    /// How many channels.
    pub count: usize,
    fill: ComputePipeline,
}

/// A fill pass: `shader` reads the batch's voxels and table of fills and writes `images` pool
/// images; `constants` specialise it.
fn fill_pipeline(
    ctx: &Arc<Context>,
    shader: &str,
    images: usize,
    constants: &[u32],
) -> Result<ComputePipeline> {
    use BindingKind::{StorageBuffer, StorageImage};
    let mut bindings = vec![StorageBuffer, StorageBuffer];
    bindings.extend(std::iter::repeat_n(StorageImage, images));
    ComputePipeline::with_constants(
        ctx,
        shader,
        &bindings,
        std::mem::size_of::<FillPush>() as u32,
        constants,
    )
}

/// Bytes of one slot of a label volume's segment indices (16 bits a texel).
const LABEL_SLOT_BYTES: usize = SLOT * SLOT * SLOT * 2;

/// Bytes of one slot of `count` mixed channels' pools (four 16-bit components a pool).
fn channel_slot_bytes(count: usize) -> usize {
    count.div_ceil(4) * SLOT * SLOT * SLOT * 8
}

impl ChannelPools {
    /// Pools for `count` channels (none for 0) of the intensity pool's `extent`.
    fn new(ctx: &Arc<Context>, count: usize, extent: [u32; 3]) -> Result<Option<Box<Self>>> {
        if count == 0 {
            return Ok(None);
        }
        if !ctx.can_write_storage(Format::R16G16B16A16_UNORM) {
            return Err(Error::Invalid(format!(
                "{} cannot write RGBA16 storage images, which the brick cache's channels fill; raise --gpu-budget so that the volume fits in core",
                ctx.info.name
            )));
        }
        let image = |name: &str| {
            Image::new(
                ctx,
                name,
                &ImageDesc::new_3d(Format::R16G16B16A16_UNORM, extent),
            )
        };
        let fill = fill_pipeline(ctx, "render/channel_fill.comp", 2, &[])?;
        Ok(Some(Box::new(ChannelPools {
            image: image("brick pool channels 0-3")?,
            image_hi: (count > 4)
                .then(|| image("brick pool channels 4-7"))
                .transpose()?,
            count,
            fill,
        })))
    }

    fn transition(&self, cmd: vellum_gpu::CommandBuffer, to: Access) {
        self.image.transition(cmd, to);
        if let Some(hi) = &self.image_hi {
            hi.transition(cmd, to);
        }
    }
}

/// The brick cache's state between frames.
pub struct Paged {
    /// The volume as a pyramid of bricks, level 0 the finest.
    pub levels: Arc<BrickLevels>,
    /// Which brick sits in which pool slot; it writes the page table's entries.
    pub cache: BrickCache,
    /// Slots along x, y, z of the pool images.
    pub grid: [usize; 3],
    /// Per page-table entry, whether a ray asked for the brick in the last frame (or read it,
    /// `USED_BIT`); the host reads it once the frame has completed.
    pub feedback: Buffer,
    /// Per page-table entry, the range of each mixed channel's texels once the brick has been
    /// read ([`UNKNOWN_RANGE`] before), entry after entry; empty without mixed channels.
    pub channel_ranges: Vec<[u16; 2]>,
    /// Page-table mode bits for the next frame (`MODE_WAIT`, `MODE_RESUME`).
    pub mode: u32,
    /// Sample level 0 everywhere instead of choosing the level by projected voxel size.
    pub finest: bool,
    /// Where the level-of-detail rule reads a level coarser than the planes, sample it at its own
    /// voxel's spacing (every second plane at level 1, every fourth at level 2, ...) instead of at
    /// every plane: a coarse level's texels then cost what its voxels are worth, as in the
    /// ray-guided renderers. The image changes only where a coarse level is read, never at
    /// `finest`. On by default; `VELLUM_LOD_STEPS=0` samples every plane, for measuring.
    pub lod_steps: bool,
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
    /// variant). On by default on a GPU, where it beat `reuse` (1.23 against 1.41 ms on an H200,
    /// BENCHMARKS.md); off on lavapipe, like `reuse`. `VELLUM_BRICK_SPAN=0|1` overrides.
    pub span: bool,
    /// A missing brick's page-table word names the finest resident coarser brick that holds it
    /// whole (`HELD_SHIFT`), where the ray caster's walk over the coarser levels then starts.
    /// On by default; `VELLUM_BRICK_HELD=0` starts every walk at the level above, for measuring
    /// and for the tests that compare the two.
    pub held: bool,
    /// In a frame that does not wait, drawn while bricks are missing, a sample that a coarser
    /// level stands in for is that level's voxel long (the ray caster's `WIDEN` variant, with
    /// `lod_steps`): a view's first frames, read mostly from the coarsest level, then take as
    /// many samples as its voxels are worth. On by default; `VELLUM_WIDEN=0` turns it off, for
    /// measuring.
    pub widen: bool,
    /// With skipping, a ray passes the bricks and sub-blocks known to hold nothing it needs in
    /// front of it in a loop that only looks them up, before its walk (the ray caster's `TRIM`
    /// variant), to the plane the walk would step to: the frame is the same. On lavapipe, where
    /// each of the walk's steps carries its sampling code for every lane, the viewer's ray cast
    /// took about 4 % less. On by default; `VELLUM_BRICK_TRIM=0` turns it off, for measuring.
    pub trim: bool,
    /// Whether the last frame's rays asked for bricks (true until a frame's feedback is read):
    /// the next frame is likely drawn around missing bricks too.
    pub asked: bool,
}

/// Words of the page table per entry.
pub(crate) const ENTRY_WORDS: usize = 2;

/// The page table's words kept between frames (by the view's state, `render::targets`), so
/// that a frame remakes only the words of the entries the cache changed since (a 2048³ store
/// has 300,000 entries, and a still frame stages the table for each of its passes).
#[derive(Default)]
pub(crate) struct PageWords {
    /// [`ENTRY_WORDS`] per entry.
    words: Vec<u32>,
    /// What the words were made under: the volume's id, the flags' key, and the cache's
    /// change-log epoch and length then.
    made: Option<(u64, u64, u64, usize)>,
}

/// A page-table entry's second word: per sub-block i of ranges `subs`, its `flags` (visible in
/// bit i, may be in focus in bit 8 + i).
fn sub_mask(subs: &vellum_volume::bricks::SubRanges, flags: &BrickFlagsOf) -> u32 {
    subs.iter().enumerate().fold(0, |m, (i, &r)| {
        let f = flags(r, &[]);
        m | (f & 1) << i | ((f >> 1) & 1) << (8 + i)
    })
}

/// The default of [`Paged::reuse`] on the device `info` describes.
pub(crate) fn brick_reuse(info: &vellum_gpu::DeviceInfo) -> bool {
    info.on_gpu_unless("VELLUM_BRICK_REUSE")
}

/// The default of [`Paged::span`] on the device `info` describes.
pub(crate) fn brick_span(info: &vellum_gpu::DeviceInfo) -> bool {
    info.on_gpu_unless("VELLUM_BRICK_SPAN")
}

/// At most `slots`, fewer where the largest pool image of that many (the channels' RGBA16 with
/// `mixed` channels, else the intensity) would pass the device's largest allocation: each pool
/// image is one, of the size the driver asks for it (2 GiB at most on lavapipe).
fn fitting_slots(ctx: &Context, mut slots: usize, mixed: usize) -> usize {
    let max = ctx.info.max_image_dimension_3d as usize;
    let limit = ctx.info.max_memory_allocation_bytes;
    let format = match mixed {
        0 => Format::R16_UNORM,
        _ => Format::R16G16B16A16_UNORM,
    };
    for _ in 0..8 {
        let extent = pool_grid(slots, max).map(|g| (g * SLOT) as u32);
        let desc = ImageDesc::new_3d(format, extent);
        let bytes = vellum_gpu::resources::image_memory_bytes(ctx, &desc);
        if bytes <= limit || slots <= 1 {
            break;
        }
        slots = (slots as f64 * limit as f64 / bytes as f64 * 0.99) as usize;
    }
    slots
}

/// Slots per axis for a pool of at most `capacity` slots, each axis within `max_texels`.
pub(crate) fn pool_grid(capacity: usize, max_texels: usize) -> [usize; 3] {
    // A page-table word holds a slot's place in 8 bits per axis.
    let m = (max_texels / SLOT).clamp(1, 255);
    // The largest g with g^k <= n.
    let root = |n: usize, k: u32| (1..=n).take_while(|g| g.pow(k) <= n).last().unwrap_or(1);
    let gx = root(capacity, 3).clamp(1, m);
    let gy = root(capacity / gx, 2).clamp(1, m);
    let gz = (capacity / (gx * gy)).clamp(1, m);
    [gx, gy, gz]
}

/// Push constants of `render/brick_fill.comp` (GLSL twin: `FillPush` in render.glsl).
#[repr(C)]
#[derive(Copy, Clone, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct FillPush {
    /// x, y: pool slots along x and y; z: `channel_fill`'s channel count (unread by
    /// `brick_fill`); w: bricks in this dispatch.
    pub grid: [i32; 4],
}

/// One brick of an upload (GLSL twin: `BrickFill` in render.glsl).
#[repr(C)]
#[derive(Copy, Clone, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct BrickFill {
    /// x: the pool slot; y: the upload's first voxel in the batch's voxel buffer; z, w unused.
    pub(crate) slot_offset: [i32; 4],
}

/// A brick to upload: its slot, its page-table entry and its voxels.
#[derive(Copy, Clone)]
pub struct Upload<'a> {
    /// The pool slot the brick goes to.
    pub slot: usize,
    /// The brick's page-table entry.
    pub entry: usize,
    /// The brick's voxels as they travel: [`UPLOAD`]³, x fastest.
    pub voxels: &'a BrickVoxels,
}

impl PagedVolume {
    /// A volume for the brick cache: pool images of as many slots as `budget_bytes` holds, nothing
    /// resident yet. `finest` samples level 0 everywhere.
    pub fn new(
        ctx: &Arc<Context>,
        levels: Arc<BrickLevels>,
        budget_bytes: u64,
        finest: bool,
    ) -> Result<Self> {
        check_pool_formats(ctx)?;
        let max = ctx.info.max_image_dimension_3d as usize;
        let mixed = levels.mixed_count();
        let labelled = levels.labels().is_some();
        let slot_bytes =
            SLOT_BYTES + channel_slot_bytes(mixed) + if labelled { LABEL_SLOT_BYTES } else { 0 };
        let mut slots = fitting_slots(ctx, (budget_bytes / slot_bytes as u64) as usize, mixed);
        if labelled {
            // The segment indices are one storage buffer, within the device's range.
            slots = slots.min(ctx.info.max_storage_buffer_range as usize / LABEL_SLOT_BYTES);
        }
        let grid = pool_grid(slots, max);
        let capacity = grid.iter().product::<usize>().min(slots);
        let mib = budget_bytes as f64 / (1 << 20) as f64;
        let cache = BrickCache::new(&levels, capacity, (mib, slot_bytes))?;
        let extent = grid.map(|g| (g * SLOT) as u32);
        let image = |name: &str, format| Image::new(ctx, name, &ImageDesc::new_3d(format, extent));
        // The in-core texture's format, so that the shaders sample both alike.
        let intensity = image("brick pool intensity", Format::R16_UNORM)?;
        let feedback = Buffer::new(
            ctx,
            "brick feedback",
            &BufferDesc::storage((levels.entries().max(1) * 4) as u64).host_read(),
        )?;
        // 8-bit bricks travel with the table that normalises them (`brick_fill.comp`); every
        // other type's, normalised to 16 bits, are copied.
        let fill = match levels.u8_table() {
            Some(_) => Some(fill_pipeline(ctx, "render/brick_fill.comp", 1, &[])?),
            None => None,
        };
        let level0 = levels.levels()[0].clone();
        let channels = ChannelPools::new(ctx, mixed, extent)?;
        let channel_ranges = vec![UNKNOWN_RANGE; levels.entries() * mixed];
        let labels = labelled
            .then(|| {
                let bytes = (capacity * LABEL_SLOT_BYTES) as u64;
                Buffer::new(ctx, "brick pool labels", &BufferDesc::storage(bytes))
            })
            .transpose()?;
        Ok(PagedVolume {
            intensity,
            range: levels.range(),
            dims: level0.dims,
            spacing: level0.spacing,
            geometry: levels.geometry,
            whole: Bricks {
                counts: [1; 3],
                range: vec![[0, u16::MAX]],
            },
            id: crate::passes::normals::next_volume_id(),
            paged: Paged {
                levels,
                cache,
                grid,
                feedback,
                channel_ranges,
                mode: 0,
                finest,
                lod_steps: std::env::var("VELLUM_LOD_STEPS").as_deref() != Ok("0"),
                pool_bytes: (capacity * slot_bytes) as u64,
                reuse: brick_reuse(&ctx.info),
                span: brick_span(&ctx.info),
                held: std::env::var("VELLUM_BRICK_HELD").as_deref() != Ok("0"),
                widen: std::env::var("VELLUM_WIDEN").as_deref() != Ok("0"),
                trim: std::env::var("VELLUM_BRICK_TRIM").as_deref() != Ok("0"),
                asked: true,
            },
            channels,
            labels,
            fill,
        })
    }

    /// Records the upload of `loads` through the frame's staging ring (pass `brick_upload`):
    /// their voxels, copied into their slots (16-bit) or written there by `brick_fill` through
    /// their table (8-bit). The pools end ready for sampling in compute.
    pub fn record_loads(&self, ctx: &Context, frame: &mut Frame, loads: &[Upload]) -> Result<()> {
        if loads.is_empty() {
            return Ok(());
        }
        frame.profiler.begin(frame.cmd, "brick_upload");
        if let Some(c) = &self.channels {
            c.transition(frame.cmd, Access::ComputeWrite);
            let all: Vec<&Upload> = loads.iter().collect();
            for part in all.chunks(FILL_BATCH) {
                self.record_channel_fill(ctx, frame, c, part)?;
            }
            c.transition(frame.cmd, Access::ComputeSampled);
        }
        if loads
            .iter()
            .any(|u| matches!(u.voxels.data, BrickData::U8(_)) != self.fill.is_some())
        {
            return Err(Error::Invalid(
                "a brick arrived of another voxel width than its pyramid's".into(),
            ));
        }
        match &self.fill {
            Some(fill) => {
                self.intensity.transition(frame.cmd, Access::ComputeWrite);
                let all: Vec<&Upload> = loads.iter().collect();
                for part in all.chunks(FILL_BATCH) {
                    self.record_fill(ctx, frame, fill, part)?;
                }
            }
            None => {
                self.intensity.transition(frame.cmd, Access::TransferWrite);
                self.record_copies(ctx, frame, loads)?;
            }
        }
        if let Some(pool) = &self.labels {
            record_label_copies(ctx, frame, pool, loads)?;
        }
        self.intensity.transition(frame.cmd, Access::ComputeSampled);
        frame.profiler.end(frame.cmd);
        Ok(())
    }

    /// One `channel_fill` dispatch over `part`: each brick's mixed channels into `pools`.
    fn record_channel_fill(
        &self,
        ctx: &Context,
        frame: &mut Frame,
        pools: &ChannelPools,
        part: &[&Upload],
    ) -> Result<()> {
        let box_len = UPLOAD * UPLOAD * UPLOAD * pools.count;
        if let Some(u) = part.iter().find(|u| u.voxels.channels.len() != box_len) {
            return Err(Error::Invalid(format!(
                "brick {} arrived with {} channel voxels; expected {box_len}",
                u.entry,
                u.voxels.channels.len()
            )));
        }
        let fills = fills_of(part);
        let voxels: Vec<&[u8]> = part
            .iter()
            .map(|u| bytemuck::cast_slice(&u.voxels.channels))
            .collect();
        let voxels = frame.staging.push_parts(&voxels, 16)?;
        let fills = frame.staging.push_parts(
            &[
                bytemuck::cast_slice(&[0u32; 128]),
                bytemuck::cast_slice(&fills),
            ],
            16,
        )?;
        ctx.count_transfer(&pools.image.name, true, voxels.size);
        let push = FillPush {
            grid: [
                self.paged.grid[0] as i32,
                self.paged.grid[1] as i32,
                pools.count as i32,
                part.len() as i32,
            ],
        };
        let slot_texels = (SLOT * SLOT * SLOT) as u32;
        pools.fill.dispatch(
            frame.cmd,
            &[
                Bind::StorageSlice(voxels),
                Bind::StorageSlice(fills),
                Bind::StorageImage(&pools.image),
                // Four or fewer channels: never written.
                Bind::StorageImage(pools.image_hi.as_ref().unwrap_or(&pools.image)),
            ],
            &push,
            [slot_texels.div_ceil(64), part.len() as u32, 1],
        )
    }

    /// 16-bit bricks into their slots: one copy of a box each, the bricks travelling as the
    /// slots hold them.
    fn record_copies(&self, ctx: &Context, frame: &mut Frame, loads: &[Upload]) -> Result<()> {
        let voxels: Vec<&[u8]> = loads.iter().map(|u| u.voxels.data.bytes()).collect();
        let src = frame.staging.push_parts(&voxels, 16)?;
        let g = self.paged.grid;
        let mut from = 0;
        let mut boxes = Vec::with_capacity(loads.len());
        for (u, bytes) in loads.iter().zip(&voxels) {
            let at = [
                u.slot % g[0],
                (u.slot / g[0]) % g[1],
                u.slot / (g[0] * g[1]),
            ];
            boxes.push(vellum_gpu::transfer::TexelBox {
                from,
                origin: at.map(|a| (a * SLOT) as u32),
                extent: [SLOT as u32; 3],
            });
            from += bytes.len() as u64;
        }
        vellum_gpu::transfer::record_upload_boxes(ctx, frame.cmd, src, &self.intensity, &boxes)
    }

    /// One `brick_fill` dispatch over `part` (8-bit bricks).
    fn record_fill(
        &self,
        ctx: &Context,
        frame: &mut Frame,
        fill: &ComputePipeline,
        part: &[&Upload],
    ) -> Result<()> {
        let fills = fills_of(part);
        let table: [u32; 128] = match self.paged.levels.u8_table() {
            Some(t) => std::array::from_fn(|i| t[2 * i] as u32 | (t[2 * i + 1] as u32) << 16),
            None => [0; 128],
        };
        let voxels: Vec<&[u8]> = part.iter().map(|u| u.voxels.data.bytes()).collect();
        let voxels = frame.staging.push_parts(&voxels, 16)?;
        let fills = frame.staging.push_parts(
            &[bytemuck::cast_slice(&table), bytemuck::cast_slice(&fills)],
            16,
        )?;
        ctx.count_transfer(&self.intensity.name, true, voxels.size);
        let slot_texels = (SLOT * SLOT * SLOT) as u32;
        let push = FillPush {
            grid: [
                self.paged.grid[0] as i32,
                self.paged.grid[1] as i32,
                // Unread: the pipeline's EIGHT_BIT says the width.
                0,
                part.len() as i32,
            ],
        };
        fill.dispatch(
            frame.cmd,
            &[
                Bind::StorageSlice(voxels),
                Bind::StorageSlice(fills),
                Bind::StorageImage(&self.intensity),
            ],
            &push,
            [slot_texels.div_ceil(64), part.len() as u32, 1],
        )
    }
}

/// Where each brick of `part` goes and where its voxels start in the batch's buffer (they follow
/// one another, [`UPLOAD`]³ each).
fn fills_of(part: &[&Upload]) -> Vec<BrickFill> {
    let per = (UPLOAD * UPLOAD * UPLOAD) as i32;
    part.iter()
        .enumerate()
        .map(|(i, u)| BrickFill {
            slot_offset: [u.slot as i32, per * i as i32, 0, 0],
        })
        .collect()
}

/// Records the copy of each upload's segment indices into its slot of the label `pool`, ordered
/// after earlier frames' reads and before this frame's.
fn record_label_copies(
    ctx: &Context,
    frame: &mut Frame,
    pool: &Buffer,
    loads: &[Upload],
) -> Result<()> {
    use vellum_gpu::commands::{copy_slice_regions, memory_transition, CopyRegion};
    let texels = SLOT * SLOT * SLOT;
    if let Some(u) = loads.iter().find(|u| u.voxels.labels.len() != texels) {
        return Err(Error::Invalid(format!(
            "brick {} arrived with {} segment indices; expected {texels}",
            u.entry,
            u.voxels.labels.len()
        )));
    }
    let parts: Vec<&[u8]> = loads
        .iter()
        .map(|u| bytemuck::cast_slice(&u.voxels.labels))
        .collect();
    let src = frame.staging.push_parts(&parts, 16)?;
    let size = LABEL_SLOT_BYTES as u64;
    let regions: Vec<CopyRegion> = loads
        .iter()
        .enumerate()
        .map(|(i, u)| CopyRegion {
            from: i as u64 * size,
            to: u.slot as u64 * size,
            size,
        })
        .collect();
    ctx.count_transfer(&pool.name, true, src.size);
    memory_transition(ctx, frame.cmd, Access::ComputeRead, Access::TransferWrite);
    copy_slice_regions(ctx, frame.cmd, &src, pool, &regions)?;
    memory_transition(ctx, frame.cmd, Access::TransferWrite, Access::ComputeRead);
    Ok(())
}

/// The pools are written as storage images: R16_UNORM needs the extended storage formats.
fn check_pool_formats(ctx: &Context) -> Result<()> {
    // R16 unorm: the pool keeps each intensity in 16 bits (`Pools::new`).
    let storage = ctx.can_write_storage(Format::R16_UNORM);
    if !(ctx.info.storage_image_extended_formats && storage) {
        return Err(Error::Invalid(format!(
            "{} cannot write R16 storage images, which the brick cache fills; raise --gpu-budget so that the volume fits in core",
            ctx.info.name
        )));
    }
    Ok(())
}

impl Paged {
    /// Whether the next frame takes the ray caster's `WIDEN` variant: its samples step over
    /// planes, it does not wait for bricks, and the last frame's rays asked for some.
    pub(crate) fn widens(&self) -> bool {
        self.lod_steps && !self.finest && self.widen && self.asked && self.mode & MODE_WAIT == 0
    }

    /// The page table's header for a frame whose samples at distance d from the eye cover
    /// `lod.0 · d + lod.1` level-0 voxels (see the module's documentation) and whose planes are
    /// chosen for level `planes` (the finest it reads); the entries, [`Paged::page_words`],
    /// follow it.
    pub(crate) fn header(&self, lod: (f32, f32), planes: usize) -> [u32; HEADER] {
        let levels = self.levels.levels();
        let (a, b) = if self.finest { (0.0, 0.0) } else { lod };
        let mut words = [0u32; HEADER];
        let s0 = levels[0].spacing;
        words[..8].copy_from_slice(&[
            levels.len() as u32,
            vellum_volume::bricks::BRICK as u32,
            SLOT as u32,
            // Bits 8-11: the planes' level, from which the ray caster's `LOD_STEPS` variant
            // (`Paged::lod_steps`) steps the samples of coarser levels (`steps_of`).
            self.mode | (planes as u32) << 8,
            self.grid[0] as u32,
            self.grid[1] as u32,
            a.to_bits(),
            b.to_bits(),
        ]);
        for (i, l) in levels.iter().enumerate() {
            // Texture coordinate (0..1 over level 0's box) to this level's voxel units.
            let scale = self.levels.texture_scale(i);
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

    /// The page table's words into `dst` ([`ENTRY_WORDS`] per entry, see [`Paged::page_word`]).
    /// `id` names the volume and `key` the flags. The words `kept` made for the same volume are
    /// kept: those of the entries the cache changed since are made again, with those of the finer
    /// bricks they overlap (whose holders may have changed), and when the flags moved every
    /// word's flags are, its holder kept (holders do not depend on the flags, and finding them
    /// all again costs a 2048³ store's 300,000 entries a walk up the levels each).
    pub(crate) fn page_words(
        &self,
        dst: &mut [u32],
        flags: &BrickFlagsOf,
        (id, key): (u64, u64),
        kept: &mut PageWords,
    ) {
        let (epoch, changes) = self.cache.changes();
        let n = self.cache.page_table.len();
        // Words made with holders named and without are not each other's.
        let id = id ^ u64::from(self.held) << 63;
        match kept.made {
            Some((i, k, e, seen))
                if (i, e) == (id, epoch)
                    && seen <= changes.len()
                    && kept.words.len() == ENTRY_WORDS * n =>
            {
                for &entry in &changes[seen..] {
                    self.remake(entry, flags, &mut kept.words, Holder::Find);
                    // A brick that came or went changes what the finer missing bricks it holds
                    // are drawn from (coarser ones first: each reads its holder's word).
                    let Some(b) = self.levels.key(entry).filter(|b| b.level > 0) else {
                        continue;
                    };
                    for e in self.levels.finer_overlapping(b) {
                        self.remake(e, flags, &mut kept.words, Holder::Find);
                    }
                }
                if k != key {
                    for e in 0..n {
                        self.remake(e, flags, &mut kept.words, Holder::Keep);
                    }
                }
            }
            _ => {
                kept.words = vec![0; ENTRY_WORDS * n];
                // The coarsest level's entries come last: make them first.
                for e in (0..n).rev() {
                    self.remake(e, flags, &mut kept.words, Holder::Find);
                }
            }
        }
        kept.made = Some((id, key, epoch, changes.len()));
        dst.copy_from_slice(&kept.words);
    }

    /// The page-table words of entry `e`: the slot's place with [`RESIDENT_BIT`], and for a
    /// brick whose range is known [`KNOWN_BIT`] and its `flags` (visible, may be in focus) in
    /// bits 24 and 25; then its sub-blocks' flags (bits i and 8 + i for sub-block i; all set with
    /// mixed channels, whose ranges are kept per brick only).
    fn page_word(
        &self,
        e: usize,
        flags: &BrickFlagsOf,
        words: &[u32],
        h: Holder,
    ) -> [u32; ENTRY_WORDS] {
        let c = &self.cache;
        let [gx, gy, _] = self.grid;
        let place = match (c.page_table[e], h) {
            (0, _) if !self.held => 0,
            (0, Holder::Find) => self.held_by(e, words),
            (0, Holder::Keep) => words[ENTRY_WORDS * e] & HELD_BITS,
            (s, _) => {
                let s = s as usize - 1;
                let at = [s % gx, (s / gx) % gy, s / (gx * gy)].map(|v| v as u32);
                RESIDENT_BIT | at[0] | at[1] << 8 | at[2] << 16
            }
        };
        let range = c.ranges[e];
        if range == UNKNOWN_RANGE {
            return [place, SUB_ALL];
        }
        let mixed = self.levels.mixed_count();
        let channels = self.channel_ranges.get(e * mixed..(e + 1) * mixed);
        let word = place | KNOWN_BIT | (flags(range, channels.unwrap_or(&[])) & 3) << 24;
        if mixed > 0 {
            return [word, SUB_ALL];
        }
        [word, sub_mask(&c.sub_ranges[e], flags)]
    }

    /// Per level, how many missing bricks have a resident brick of that level named as their
    /// holder now (the words made afresh, as a frame's first pass makes them).
    pub fn holders_named(&self) -> Vec<usize> {
        let n = self.cache.page_table.len();
        let mut words = vec![0; ENTRY_WORDS * n];
        let none = |_: [u16; 2], _: &[[u16; 2]]| 0;
        let mut named = vec![0; self.levels.levels().len()];
        for e in (0..n).rev() {
            self.remake(e, &none, &mut words, Holder::Find);
            let w = words[ENTRY_WORDS * e];
            if w & RESIDENT_BIT == 0 && w >> HELD_SHIFT != 0 {
                named[(w >> HELD_SHIFT) as usize] += 1;
            }
        }
        named
    }

    /// Makes entry `e`'s words in `words` again.
    fn remake(&self, e: usize, flags: &BrickFlagsOf, words: &mut [u32], h: Holder) {
        let w = self.page_word(e, flags, words, h);
        words[ENTRY_WORDS * e..ENTRY_WORDS * (e + 1)].copy_from_slice(&w);
    }

    /// For missing brick `e`: the finest resident coarser brick that holds all of its samples
    /// (`BrickLevels::holder`), as its level from bit [`HELD_SHIFT`] on; 0 when none is found (a
    /// level on the way does not hold it whole in one brick, which happens only where levels do
    /// not halve exactly), and the ray caster walks from the level above. Its holder one level up
    /// is that brick when resident, else that brick's own holder, read from `words` (which holds
    /// the coarser levels' words).
    fn held_by(&self, e: usize, words: &[u32]) -> u32 {
        let Some(key) = self.levels.key(e) else {
            return 0;
        };
        let level = key.level + 1;
        if level >= self.levels.levels().len() {
            return 0;
        }
        let Some(brick) = self.levels.holder(key, level) else {
            return 0;
        };
        let holder = self.levels.entry(BrickKey { level, brick });
        match self.cache.page_table[holder] {
            0 => words[ENTRY_WORDS * holder] & HELD_BITS,
            _ => (level as u32) << HELD_SHIFT,
        }
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
        self.asked = !f.wanted.is_empty();
        Ok(f)
    }

    /// Records the clearing of the feedback buffer, before the frame's ray casting writes it.
    pub(crate) fn record_clear_feedback(&self, ctx: &Context, frame: &mut Frame) {
        vellum_gpu::commands::memory_transition(
            ctx,
            frame.cmd,
            Access::HostRead,
            Access::TransferWrite,
        );
        vellum_gpu::commands::fill_buffer(ctx, frame.cmd, &self.feedback, 0);
        vellum_gpu::commands::memory_transition(
            ctx,
            frame.cmd,
            Access::TransferWrite,
            Access::ComputeReadWrite,
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use vellum_gpu::interface::assert_glsl_layout;

    /// Each sub-block's flags land in its own bits: visible in bit i, focus in bit 8 + i.
    #[test]
    fn a_sub_blocks_flags_are_its_own() {
        // Visible above 30,000, in focus above 50,000: by each range's top.
        let flags =
            |r: [u16; 2], _: &[[u16; 2]]| (r[1] > 30_000) as u32 | ((r[1] > 50_000) as u32) << 1;
        let mut subs = [[0, 100]; 8];
        subs[3] = [0, 40_000];
        subs[6] = [20_000, 60_000];
        assert_eq!(sub_mask(&subs, &flags), 1 << 3 | 1 << 6 | 1 << (8 + 6));
        assert_eq!(sub_mask(&[[0, 65_535]; 8], &flags), SUB_ALL);
    }

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

    #[test]
    fn fill_interfaces_match_glsl() {
        assert_glsl_layout!(FillPush, "render.glsl", "FillPush", [grid]);
        assert_glsl_layout!(BrickFill, "render.glsl", "BrickFill", [slot_offset]);
    }
}
