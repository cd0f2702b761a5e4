//! The host side of the brick cache (issue 26): a volume as a pyramid of fixed-size bricks, the
//! bricks' texels as the renderer samples them, and which brick sits in which slot of the GPU's
//! pool. Nothing here knows about Vulkan; `passes::paging` owns the pool images and records the
//! uploads.
//!
//! ## Layout
//! Every level is cut into bricks of [`BRICK`]³ voxels. A pool slot holds a brick with a two-voxel
//! apron on every side ([`SLOT`]³ texels), so that the ray caster's Sobel gradient at a sample
//! anywhere inside the brick (26 trilinear fetches a voxel around it) reads only its own slot.
//! Voxels outside the level repeat its nearest edge voxel, as a clamp-to-edge sampler does, so a
//! bricked sample and its gradient equal the in-core ones at every position.
//!
//! The pyramid is the store's levels (or, for a volume in memory, the volume itself), continued by
//! 2×2×2 means in memory until the coarsest level is one brick: that level is always resident, so
//! every sample has something to fall back to.
//!
//! ## Texels
//! Intensities are normalised to u16 over level 0's value range, exactly as
//! [`Volume::normalised_u16`] does for the in-core texture: the pool holds what the in-core
//! intensity texture holds, brick by brick. It holds no gradients: the ray caster makes each
//! shaded sample's from the intensity (`shade.glsl`'s `sobel_at`), which is what the in-core
//! gradient texture interpolates to, so that a slot takes 2 bytes a texel, not 10.
//!
//! ## Slots
//! [`BrickCache`] hands out slots: the coarsest level's first and for good, then the bricks a
//! frame asks for most, evicting the least recently used bricks no ray asked for this time
//! (used: loaded, or read by a frame that said so, [`BrickCache::touch`]).

use crate::chunks::{Chunk, ChunkCache};
use crate::io::ome_zarr::Multiscale;
use crate::source::BoxSource;
use crate::{Volume, VoxelData};
use std::collections::HashMap;
use std::sync::Arc;
use vellum_error::{Error, Result};

/// Edge of a brick in voxels.
pub const BRICK: usize = 32;
/// Apron voxels on each side of a brick in its slot: trilinear filtering inside the brick reads
/// one, and the Sobel operator's fetches a voxel either side of a sample read one more.
pub(crate) const APRON: usize = 2;
/// Edge of a pool slot in texels.
pub const SLOT: usize = BRICK + 2 * APRON;
/// Edge of a sub-block in voxels: a brick is cut into 2×2×2 of them, each with its own range, so
/// that a ray walks past the empty part of a brick that is not all empty (the in-core skipping
/// grid's edge, `passes::normals::BRICK`).
pub const SUB: usize = BRICK / 2;
/// A brick's sub-blocks' ranges, sub-block qx + 2 qy + 4 qz (each q 0 or 1 along its axis): each
/// over the texels a trilinear sample inside the sub-block blends, its voxels and one more on each
/// side. Together they cover the slot's texels, so their union is the brick's range.
pub type SubRanges = [[u16; 2]; 8];
/// The sub-blocks' ranges of an entry whose brick has not been read yet.
pub const UNKNOWN_SUB_RANGES: SubRanges = [UNKNOWN_RANGE; 8];
/// Bytes a voxel takes in the renderer's textures in core: R16 intensity and RGBA16F gradient.
pub(crate) const TEXTURE_BYTES_PER_VOXEL: u64 = 2 + 8;
/// Bytes a voxel takes in core with no gradient texture: its R16 intensity alone (the ray caster
/// then makes each shaded sample's gradient from it).
pub(crate) const INTENSITY_BYTES_PER_VOXEL: u64 = 2;
/// Bytes of one slot: its R16 intensity texels (the pool holds no gradients).
pub const SLOT_BYTES: usize = SLOT * SLOT * SLOT * INTENSITY_BYTES_PER_VOXEL as usize;

/// Bytes the renderer's textures of a volume of `dims` take in core.
pub fn in_core_bytes(dims: [usize; 3]) -> u64 {
    dims.iter().map(|&n| n as u64).product::<u64>() * TEXTURE_BYTES_PER_VOXEL
}

/// Bytes the intensity texture alone of a volume of `dims` takes in core: the least a volume
/// drawn whole needs.
pub fn intensity_bytes(dims: [usize; 3]) -> u64 {
    dims.iter().map(|&n| n as u64).product::<u64>() * INTENSITY_BYTES_PER_VOXEL
}
/// Most levels a pyramid may have (the page table's header has room for this many).
pub const MAX_LEVELS: usize = 16;

/// One level as the cache sees it.
#[derive(Clone, Debug, PartialEq)]
pub struct PagedLevel {
    /// Voxels along x, y, z.
    pub dims: [usize; 3],
    /// Voxel size along x, y, z.
    pub spacing: [f64; 3],
    /// Bricks along x, y, z.
    pub counts: [usize; 3],
    /// The level's first page-table entry.
    pub first: usize,
}

impl PagedLevel {
    /// Bricks in the level.
    pub fn bricks(&self) -> usize {
        self.counts.iter().product()
    }
}

/// A brick: its level and position in that level's brick grid, and its page-table entry.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash)]
pub struct BrickKey {
    /// The level, 0 the finest.
    pub level: usize,
    /// The brick's position in the level's brick grid.
    pub brick: [usize; 3],
}

/// Where a level's voxels come from.
enum LevelSource {
    Store(Arc<Multiscale>, usize),
    Memory(Volume),
}

impl LevelSource {
    fn source(&self) -> Result<Box<dyn BoxSource + '_>> {
        Ok(match self {
            LevelSource::Store(ms, l) => Box::new(ms.level(*l)?),
            LevelSource::Memory(v) => Box::new(v),
        })
    }
}

/// Edge of the box a brick travels to the GPU in: its slot, texel for texel.
pub const UPLOAD: usize = SLOT;

/// A brick's voxels as they travel: normalised u16, or 8-bit as they are.
#[derive(Clone, Debug, PartialEq)]
pub enum BrickData {
    /// 8-bit voxels as they are (the shader maps them through a table).
    U8(Vec<u8>),
    /// Voxels normalised to 16 bits.
    U16(Vec<u16>),
}

impl BrickData {
    /// The bytes that travel.
    pub fn bytes(&self) -> &[u8] {
        match self {
            BrickData::U8(v) => v,
            BrickData::U16(v) => bytemuck::cast_slice(v),
        }
    }
}

/// One brick as it travels to the GPU (x fastest, [`UPLOAD`]³ voxels), the range of the
/// normalised texels its trilinear samples blend (every sample inside the brick lies in it), and
/// whether every voxel of the upload has one value (the slot is then that value throughout, its
/// gradient 0).
#[derive(Clone, Debug)]
pub struct BrickVoxels {
    /// The voxels.
    pub data: BrickData,
    /// The range of the normalised texels trilinear samples inside the brick blend.
    pub range: [u16; 2],
    /// The ranges of the brick's sub-blocks' texels ([`SubRanges`]).
    pub sub_ranges: SubRanges,
    /// Whether every voxel of the upload has one value (and, with mixed channels, every
    /// channel's too; with a label volume, every texel one segment).
    pub constant: bool,
    /// The mixed channels' voxels of the same upload box ([`BrickLevels::mix`]), channel after
    /// channel in mixing order, each normalised to 16 bits over its own range; empty without.
    pub channels: Vec<u16>,
    /// Per mixed channel, the range of its slot's texels.
    pub channel_ranges: Vec<[u16; 2]>,
    /// With a label volume beside the pyramid ([`BrickLevels::set_labels`]): the segment index
    /// of each of the slot's texels ([`SLOT`]³, x fastest), from its level's indices (a coarse
    /// level's by [`crate::labels::coarser_index`]); empty without.
    pub labels: Vec<u16>,
}

impl BrickVoxels {
    /// Bytes that travel to the GPU: the voxels, the mixed channels' and the segment indices.
    pub fn travel_bytes(&self) -> u64 {
        (self.data.bytes().len() + 2 * (self.channels.len() + self.labels.len())) as u64
    }
}

/// The one value every chunk of `got` holds, when they hold one and the same.
fn one_value_of(got: &[([usize; 3], Arc<Chunk>)]) -> Option<f64> {
    let v = got.first()?.1.value()?;
    got.iter().all(|(_, c)| c.value() == Some(v)).then_some(v)
}

/// Whether `VELLUM_DIRECT_GATHER=0` asks the loaders to paste a brick's box out of its chunks
/// and gather the upload from that box, as they did before [`gather_chunks`] (for measuring).
fn no_direct_gather() -> bool {
    static OFF: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *OFF.get_or_init(|| std::env::var("VELLUM_DIRECT_GATHER").as_deref() == Ok("0"))
}

/// A volume as a pyramid of bricks, read brick by brick.
pub struct BrickLevels {
    levels: Vec<PagedLevel>,
    sources: Vec<LevelSource>,
    /// Data values that map to normalised 0 and 1 ([`BrickLevels::range`]).
    range: [f64; 2],
    /// Level 0's placement (origin; a store has no directions).
    pub geometry: crate::geometry::Geometry,
    /// The store's decoded chunks, shared by the threads that read bricks.
    chunks: ChunkCache,
    /// Channels mixed in the ray beside this pyramid's voxels, in mixing order.
    mixed: Vec<Mixed>,
    /// A label volume on level 0's grid, held whole on the host (2 bytes a voxel), and the
    /// segment indices of each coarser level ([`crate::labels::coarser_index`], a seventh more):
    /// each brick carries its slot's ([`BrickVoxels::labels`]).
    labels: Option<(Arc<crate::labels::Labels>, Vec<Vec<u16>>)>,
    /// The last level of at most [`RANGE_CHECK_VOXELS`] read whole, with its index: the range's
    /// level when the store was opened, which the `auto` window and the previews read again
    /// ([`BrickLevels::read_small_level`]); from a server, a round trip less before the first
    /// frame.
    small: std::sync::Mutex<Option<(usize, Volume)>>,
    /// Per level of a store in a folder, the chunks it leaves out
    /// ([`crate::io::ome_zarr::Multiscale::absent_chunks`]): a brick that meets only those holds
    /// their fill value, known before it is read ([`BrickLevels::known_uniform`]).
    absent: Vec<Option<crate::io::ome_zarr::AbsentChunks>>,
    /// How the levels' bricks nest, per pair of levels.
    nesting: nesting::Nesting,
}

/// A channel mixed in the ray (issue 42): each brick read carries every mixed channel's voxels,
/// so that they go to one pool slot together.
pub enum Mixed {
    /// This pyramid's own voxels (the focus channel, over the pyramid's range).
    Own,
    /// Another channel's pyramid on the same grid, over its own range.
    Other(Box<BrickLevels>),
}

/// Bytes of decoded chunks a pyramid keeps by default (`--memory-budget` sets it).
pub(crate) const DEFAULT_CHUNK_CACHE: u64 = 896 << 20;

/// The finest level of `ms` of at most `voxels` voxels, or its coarsest when none is that small.
fn small_level(ms: &Multiscale, voxels: usize) -> usize {
    ms.finest_within(voxels).unwrap_or(ms.levels.len() - 1)
}

/// Voxels of the level a recorded range is checked against at most (a 128³ level).
const RANGE_CHECK_VOXELS: usize = 1 << 21;

/// The range `ms` records (`vellum.range`), if its coarse level's values lie within it: a
/// level's voxels are means of level 0's, so none may fall outside level 0's extremes. A range
/// that is not finite, whose span is not, or that its own coarse level contradicts would draw a
/// black or saturated picture through the cache: refused in one sentence.
fn check_recorded_range(
    ms: &Multiscale,
    r: [f64; 2],
    (pick, level): (usize, &Volume),
) -> Result<[f64; 2]> {
    let name = "its recorded range (attributes vellum.range)";
    if !(r[0].is_finite() && r[1].is_finite() && (r[1] - r[0]).is_finite()) {
        return Err(Error::format(
            &ms.root,
            format!("{name} {r:?} is not a finite span; expected the smallest and largest value of level 0"),
        ));
    }
    let seen = level.normalised_range();
    let slack = 1e-6 * r[0].abs().max(r[1].abs()).max(1e-30);
    if seen[0] < r[0] - slack || seen[1] > r[1] + slack {
        return Err(Error::format(
            &ms.root,
            format!(
                "{name} {r:?} does not hold the values of its level {} ({} .. {}); expected the smallest and largest value of level 0 (remove the attribute to have it measured)",
                ms.levels[pick].path, seen[0], seen[1]
            ),
        ));
    }
    Ok(r)
}

impl BrickLevels {
    /// The pyramid of a volume in memory: the volume, then 2×2×2 means down to one brick.
    pub fn of_volume(v: Volume) -> Result<Self> {
        let range = v.normalised_range();
        let geometry = v.geometry;
        Self::build(vec![LevelSource::Memory(v)], range, geometry)
    }

    /// The pyramid of a store: its levels, continued down to one brick. The intensity range is
    /// the one vellum recorded when it wrote the store; a store written elsewhere has its range
    /// taken from its finest level of at most `scan_limit` voxels (said once at run time when
    /// that is not level 0: extremes thinner than that level's voxels are then clipped).
    pub fn of_store(ms: Arc<Multiscale>, scan_limit: usize) -> Result<Self> {
        let (range, read) = match ms.range {
            Some(r) => {
                let pick = small_level(&ms, RANGE_CHECK_VOXELS);
                let level = ms.read_level(pick)?;
                (check_recorded_range(&ms, r, (pick, &level))?, (pick, level))
            }
            None => {
                // The finest level small enough (level 0 when it is).
                let pick = small_level(&ms, scan_limit);
                if pick > 0 {
                    log::warn!(
                        "{} does not record its value range; taking it from level {pick}, so extremes finer than that level may be clipped",
                        ms.root.display()
                    );
                }
                let level = ms.read_level(pick)?;
                (level.normalised_range(), (pick, level))
            }
        };
        let geometry = ms.geometry_of(0);
        let sources = (0..ms.levels.len())
            .map(|l| LevelSource::Store(ms.clone(), l))
            .collect();
        let mut levels = Self::build(sources, range, geometry)?;
        levels.keep_small(read);
        // Not knowing them only costs reading those bricks: a level whose chunks cannot be
        // looked for reads as before.
        levels.absent = (0..ms.levels.len())
            .map(|l| ms.absent_chunks(l).ok().flatten())
            .collect();
        Ok(levels)
    }

    fn build(
        mut sources: Vec<LevelSource>,
        range: [f64; 2],
        geometry: crate::geometry::Geometry,
    ) -> Result<Self> {
        let mut levels: Vec<PagedLevel> = Vec::new();
        loop {
            let i = levels.len();
            let Some(src) = sources.get(i) else { break };
            let s = src.source()?;
            let dims = s.dims();
            let counts = dims.map(|n| n.div_ceil(BRICK));
            let first = levels.last().map_or(0, |l| l.first + l.bricks());
            levels.push(PagedLevel {
                dims,
                spacing: s.spacing(),
                counts,
                first,
            });
            let coarsest = i + 1 == sources.len();
            if coarsest && counts.iter().any(|&c| c > 1) {
                // Continue the pyramid in memory: this level is small enough to read whole
                // once it is the store's coarsest (at most a few bricks per axis).
                let whole = s.read_box([0; 3], dims)?;
                drop(s);
                sources.push(LevelSource::Memory(crate::io::ome_zarr::halve(&whole)?));
            }
            if levels.len() > MAX_LEVELS {
                return Err(Error::Invalid(format!(
                    "the volume needs more than {MAX_LEVELS} levels to reach one brick"
                )));
            }
        }
        let mut pyramid = BrickLevels {
            levels,
            sources,
            range,
            geometry,
            chunks: ChunkCache::new(DEFAULT_CHUNK_CACHE),
            mixed: Vec::new(),
            labels: None,
            small: std::sync::Mutex::new(None),
            absent: Vec::new(),
            nesting: nesting::Nesting::default(),
        };
        pyramid.nesting = nesting::Nesting::of(&pyramid);
        Ok(pyramid)
    }

    /// The pyramid of the store at `path` (the time point and channel of `pick`) when `path` is
    /// a store whose level 0 does not `fit` (given its voxels along x, y, z); `None` when it is
    /// not a store or fits (level 0 is never read here).
    pub fn of_store_beyond(
        path: &std::path::Path,
        fits: impl FnOnce([usize; 3]) -> bool,
        pick: crate::io::ome_zarr::Pick,
    ) -> Result<Option<Self>> {
        use crate::io::ome_zarr;
        if !ome_zarr::is_store(path) {
            return Ok(None);
        }
        let ms = ome_zarr::Multiscale::open_picked(path, pick)?;
        if fits(ms.levels[0].dims) {
            return Ok(None);
        }
        // A level is read whole for the range only when it is small (16 Mi voxels).
        Ok(Some(Self::of_store(Arc::new(ms), 1 << 24)?))
    }

    /// The data values that map to normalised 0 and 1.
    pub fn range(&self) -> [f64; 2] {
        self.range
    }

    /// Maps `range` to normalised 0 and 1 from now on. The chunk cache, which keeps chunks
    /// normalised over the range, is emptied.
    pub fn set_range(&mut self, range: [f64; 2]) {
        self.range = range;
        self.chunks = ChunkCache::new(self.chunks.budget());
    }

    /// The levels, finest first.
    pub fn levels(&self) -> &[PagedLevel] {
        &self.levels
    }

    /// The finest level of at most `voxels` voxels, read whole (for a histogram or a preview).
    pub fn read_small_level(&self, voxels: usize) -> Result<Volume> {
        let i = self
            .levels
            .iter()
            .position(|l| l.dims.iter().product::<usize>() <= voxels)
            .unwrap_or(self.levels.len() - 1);
        let kept = self.small.lock().unwrap_or_else(|p| p.into_inner());
        if let Some((_, v)) = kept.as_ref().filter(|k| k.0 == i) {
            return Ok(v.clone());
        }
        drop(kept);
        let dims = self.levels[i].dims;
        let v = self.sources[i].source()?.read_box([0; 3], dims)?;
        self.keep_small((i, v.clone()));
        Ok(v)
    }

    /// Keeps `read` (a level's index and its voxels) for [`BrickLevels::read_small_level`] when
    /// it is small enough to keep.
    fn keep_small(&self, read: (usize, Volume)) {
        if read.1.dims.iter().product::<usize>() <= RANGE_CHECK_VOXELS {
            *self.small.lock().unwrap_or_else(|p| p.into_inner()) = Some(read);
        }
    }

    /// Page-table entries over all levels.
    pub fn entries(&self) -> usize {
        self.levels.last().map_or(0, |l| l.first + l.bricks())
    }

    /// The page-table entry of `key`.
    pub fn entry(&self, key: BrickKey) -> usize {
        let l = &self.levels[key.level];
        let [x, y, z] = key.brick;
        l.first + x + l.counts[0] * (y + l.counts[1] * z)
    }

    /// The brick of page-table entry `entry`.
    pub fn key(&self, entry: usize) -> Option<BrickKey> {
        let level = self
            .levels
            .iter()
            .position(|l| entry >= l.first && entry < l.first + l.bricks())?;
        let l = &self.levels[level];
        let i = entry - l.first;
        Some(BrickKey {
            level,
            brick: [
                i % l.counts[0],
                (i / l.counts[0]) % l.counts[1],
                i / (l.counts[0] * l.counts[1]),
            ],
        })
    }

    /// The voxels of brick `key` as they travel to the GPU: the slot's texels (the brick and
    /// its two-voxel apron, which the ray caster's Sobel fetches read), normalised to u16 over
    /// [`BrickLevels::range`] or, for 8-bit data, as they are (the GPU maps them through
    /// [`BrickLevels::u8_table`]). Voxels outside the level repeat its nearest edge voxel.
    pub fn voxels(&self, key: BrickKey) -> Result<BrickVoxels> {
        let mut v = self.own_voxels(key)?;
        if self.labels.is_some() {
            v.labels = self.slot_labels(key);
            let first = v.labels[0];
            v.constant &= v.labels.iter().all(|&i| i == first);
        }
        if self.mixed.is_empty() {
            return Ok(v);
        }
        let n = UPLOAD * UPLOAD * UPLOAD;
        let mut all = Vec::with_capacity(n * self.mixed.len());
        for m in &self.mixed {
            match m {
                Mixed::Own => self.extend_u16(&mut all, &v.data),
                Mixed::Other(l) => l.extend_u16(&mut all, &l.own_voxels(key)?.data),
            }
        }
        // One value only when every channel has one too: the slot of those values is shared.
        for c in all.chunks(n) {
            let (range, constant) = box_stats(c);
            v.channel_ranges.push(range);
            v.constant &= constant;
        }
        v.channels = all;
        Ok(v)
    }

    /// Mixes `mixed` in every brick read from now on (see [`Mixed`]): each other channel's
    /// pyramid must have this one's levels.
    pub fn mix(&mut self, mixed: Vec<Mixed>) -> Result<()> {
        for m in &mixed {
            if let Mixed::Other(l) = m {
                if l.levels != self.levels {
                    return Err(Error::Invalid(
                        "a mixed channel's levels differ from the volume's; expected channels of one grid".into(),
                    ));
                }
            }
        }
        self.mixed = mixed;
        Ok(())
    }

    /// Makes every brick read from now on carry `labels`' segment indices for its slot
    /// ([`BrickVoxels::labels`]), each coarser level's made here from the finer one's; the label
    /// volume (`what` names it in a refusal) must lie on level 0's grid.
    pub fn set_labels(&mut self, labels: Arc<crate::labels::Labels>, what: &str) -> Result<()> {
        labels.check_grid(self.levels[0].dims, what)?;
        let background = labels.index_of(0).map(|i| i as u16);
        let mut coarse: Vec<Vec<u16>> = Vec::with_capacity(self.levels.len() - 1);
        for l in 1..self.levels.len() {
            let (fine, level) = (&self.levels[l - 1], &self.levels[l]);
            let ratio = std::array::from_fn(|a| level.spacing[a] / fine.spacing[a]);
            let finer = coarse.last().unwrap_or(&labels.index);
            let next =
                crate::labels::coarser_index(finer, fine.dims, level.dims, ratio, background);
            coarse.push(next);
        }
        self.labels = Some((labels, coarse));
        Ok(())
    }

    /// The label volume each brick carries, if any ([`BrickLevels::set_labels`]).
    pub fn labels(&self) -> Option<&Arc<crate::labels::Labels>> {
        self.labels.as_ref().map(|l| &l.0)
    }

    /// The segment index of each texel of brick `key`'s slot, x fastest, from its level's
    /// indices (the slot's apron repeats the level's edge voxels, as its intensity does); empty
    /// without a label volume.
    fn slot_labels(&self, key: BrickKey) -> Vec<u16> {
        let Some((labels, coarse)) = &self.labels else {
            return Vec::new();
        };
        let index = match key.level {
            0 => &labels.index,
            l => &coarse[l - 1],
        };
        let dims = self.levels[key.level].dims;
        // Slot texel s holds the level's voxel brick · BRICK − APRON + s, clamped.
        let axis = |a: usize| -> Vec<usize> {
            (0..SLOT)
                .map(|s| {
                    let v = (key.brick[a] * BRICK + s) as i64 - APRON as i64;
                    v.clamp(0, dims[a] as i64 - 1) as usize
                })
                .collect()
        };
        let [xs, ys, zs] = [axis(0), axis(1), axis(2)];
        let [nx, ny, _] = dims;
        let mut out = Vec::with_capacity(SLOT * SLOT * SLOT);
        for &z in &zs {
            for &y in &ys {
                let row = &index[(z * ny + y) * nx..][..nx];
                out.extend(xs.iter().map(|&x| row[x]));
            }
        }
        out
    }

    /// How many channels each brick carries (0: none mixed).
    pub fn mixed_count(&self) -> usize {
        self.mixed.len()
    }

    /// `data` (this pyramid's) as normalised 16-bit values, appended to `out`.
    fn extend_u16(&self, out: &mut Vec<u16>, data: &BrickData) {
        match (data, self.u8_table()) {
            (BrickData::U16(v), _) => out.extend_from_slice(v),
            (BrickData::U8(v), Some(t)) => out.extend(v.iter().map(|&b| t[b as usize])),
            (BrickData::U8(v), None) => out.extend(v.iter().map(|&b| b as u16 * 257)),
        }
    }

    /// The box of level voxels brick `key`'s upload reads (its slot, clamped into the level):
    /// first voxel and size; and the upload's first voxel, which may lie outside the level.
    fn upload_box(&self, key: BrickKey) -> ([usize; 3], [usize; 3], [i64; 3]) {
        let dims = self.levels[key.level].dims;
        let lo: [i64; 3] = std::array::from_fn(|a| (key.brick[a] * BRICK) as i64 - APRON as i64);
        let clamp = |v: i64, a: usize| v.clamp(0, dims[a] as i64 - 1) as usize;
        let inner_lo: [usize; 3] = std::array::from_fn(|a| clamp(lo[a], a));
        let inner_hi: [usize; 3] = std::array::from_fn(|a| clamp(lo[a] + UPLOAD as i64 - 1, a) + 1);
        let size: [usize; 3] = std::array::from_fn(|a| inner_hi[a] - inner_lo[a]);
        (inner_lo, size, lo)
    }

    /// The normalised value of brick `key`'s every texel when that is known without reading it:
    /// a brick of a store in a folder whose upload meets only chunks the store leaves out holds
    /// their fill value (what [`BrickLevels::voxels`] would read, range and all). `None` with
    /// mixed channels or a label volume, whose bricks carry more than this pyramid's voxels.
    pub fn known_uniform(&self, key: BrickKey) -> Option<u16> {
        if !self.mixed.is_empty() || self.labels.is_some() {
            return None;
        }
        let absent = self.absent.get(key.level)?.as_ref()?;
        let LevelSource::Store(ms, l) = &self.sources[key.level] else {
            return None;
        };
        let (lo, size, _) = self.upload_box(key);
        let chunk = ms.levels[*l].chunk;
        crate::io::ome_zarr::chunks_meeting(chunk, lo, size)
            .all(|c| absent.is_absent(c))
            .then(|| self.uniform_u16(absent.value, ms.voxel))
    }

    /// [`BrickLevels::voxels`] of this pyramid alone.
    fn own_voxels(&self, key: BrickKey) -> Result<BrickVoxels> {
        let dims = self.levels[key.level].dims;
        let clamp = |v: i64, a: usize| v.clamp(0, dims[a] as i64 - 1) as usize;
        let (inner_lo, size, lo) = self.upload_box(key);
        let (inner, normalised) = match &self.sources[key.level] {
            LevelSource::Store(ms, l) => {
                let got = self.chunks_meeting(ms, *l, inner_lo, size)?;
                if let Some(v) = one_value_of(&got) {
                    return Ok(self.uniform_brick(v, ms.voxel));
                }
                if self.normalises(ms) && !no_direct_gather() {
                    let g = |a: usize| (0..UPLOAD as i64).map(|i| clamp(lo[a] + i, a)).collect();
                    let at = std::array::from_fn(g);
                    let uniform = |v: f64| self.uniform_u16(v, ms.voxel);
                    if let Some(b) = gather_chunks(&got, ms.levels[*l].chunk, &at, uniform) {
                        return Ok(b);
                    }
                }
                (
                    self.paste_chunks(ms, *l, &got, inner_lo, size)?,
                    self.normalises(ms),
                )
            }
            LevelSource::Memory(v) => (v.read_box(inner_lo, size)?, false),
        };
        let map: [Vec<usize>; 3] = std::array::from_fn(|a| {
            (0..UPLOAD as i64)
                .map(|i| clamp(lo[a] + i, a) - inner_lo[a])
                .collect()
        });
        let table = self.u8_table();
        let convert = match normalised {
            true => Convert::Normalised,
            false => table
                .as_ref()
                .map_or(Convert::Range(self.range), Convert::Table),
        };
        Ok(to_upload(&inner, &map, convert))
    }

    /// Whether the chunk cache keeps `ms`'s chunks of many values normalised to 16 bits (as
    /// the bricks travel), converted once when decoded rather than at each of the eight bricks
    /// and the apron reads of the 56 around that read them: every store but an 8-bit one, whose
    /// voxels travel as they are.
    fn normalises(&self, ms: &Multiscale) -> bool {
        ms.voxel != crate::VoxelType::U8
    }

    /// The decoded chunks of level `level` of `ms` that voxels `lo .. lo + size` meet, with
    /// their first voxels, each decoded once while it stays in [`BrickLevels::chunks`]. Chunks
    /// the store left out when it was opened are their fill value, unread.
    fn chunks_meeting(
        &self,
        ms: &Multiscale,
        level: usize,
        lo: [usize; 3],
        size: [usize; 3],
    ) -> Result<Vec<([usize; 3], Arc<Chunk>)>> {
        let l = &ms.levels[level];
        let (chunk, dims) = (l.chunk, l.dims);
        let listed = self.absent.get(level).and_then(Option::as_ref);
        let mut got = Vec::with_capacity(8);
        for c in crate::io::ome_zarr::chunks_meeting(chunk, lo, size) {
            let clo: [usize; 3] = std::array::from_fn(|a| c[a] * chunk[a]);
            let csize: [usize; 3] = std::array::from_fn(|a| chunk[a].min(dims[a] - clo[a]));
            let one = match listed.filter(|a| a.is_absent(c)) {
                Some(a) => Arc::new(Chunk::of_value(a.value, ms.voxel, csize, l.spacing)?),
                None => self.read_chunk(ms, (level, c), (clo, csize), listed)?,
            };
            got.push((clo, one));
        }
        Ok(got)
    }

    /// Voxels `lo .. lo + size` of level `level` of `ms`, pasted from `got`
    /// ([`BrickLevels::chunks_meeting`]) in the type the cache keeps them in.
    fn paste_chunks(
        &self,
        ms: &Multiscale,
        level: usize,
        got: &[([usize; 3], Arc<Chunk>)],
        lo: [usize; 3],
        size: [usize; 3],
    ) -> Result<Volume> {
        let l = &ms.levels[level];
        // The box in the type the cache keeps the chunks in.
        let normalised = self.normalises(ms);
        let voxel = match normalised {
            true => crate::VoxelType::U16,
            false => ms.voxel,
        };
        let data = VoxelData::zeros(voxel, size.iter().product());
        let mut out = Volume::new(size, l.spacing, data)?;
        for (clo, c) in got {
            match (c.uniform, c.value()) {
                // One voxel stands for the chunk: spread it over the chunk's part of the box.
                (true, Some(v)) if normalised => {
                    let one = VoxelData::U16(vec![self.uniform_u16(v, ms.voxel)]);
                    fill_box(&one, (*clo, c.dims), &mut out, lo)
                }
                (true, _) => fill_box(&c.volume.data, (*clo, c.dims), &mut out, lo),
                (false, _) => out.paste(&c.volume, *clo, lo),
            }
        }
        Ok(out)
    }

    /// Chunk `c` of level `level` (its voxels `clo .. clo + csize`) through the chunk cache: a
    /// chunk of many values normalised to 16 bits where [`BrickLevels::normalises`] says so, one
    /// of one value as its value.
    /// Where the store's chunks were `listed` when it was opened (and this one was in it), a
    /// chunk that reads as one value and is no longer in the store vanished while it was read
    /// (zarrs reads a missing chunk as the fill value): its sentence.
    fn read_chunk(
        &self,
        ms: &Multiscale,
        (level, c): (usize, [usize; 3]),
        (clo, csize): ([usize; 3], [usize; 3]),
        listed: Option<&crate::io::ome_zarr::AbsentChunks>,
    ) -> Result<Arc<Chunk>> {
        let spacing = ms.levels[level].spacing;
        let shape = (ms.voxel, csize.iter().product());
        let [lo, hi] = self.range;
        let scale = crate::normalise::scale_of([lo, hi]);
        let normalised = self.normalises(ms);
        let decode = |buf: &mut VoxelData| ms.read_box_into(level, clo, csize, buf);
        let keep = |buf: &VoxelData| {
            let kept = |d: &VoxelData| match normalised {
                true => VoxelData::U16(d.normalised(lo, scale)),
                false => d.clone(),
            };
            let chunk = Chunk::of_decoded(buf, csize, spacing, kept)?;
            if listed.is_some() && chunk.uniform && ms.holds_chunk(level, c) == Some(false) {
                return Err(ms.vanished(level, c));
            }
            Ok(chunk)
        };
        self.chunks.get_decoded((level, c), shape, decode, keep)
    }

    /// A brick whose voxels, apron included, all hold `value` (of a store of type `voxel`): what
    /// [`BrickLevels::voxels`] would make of it voxel by voxel.
    fn uniform_brick(&self, value: f64, voxel: crate::VoxelType) -> BrickVoxels {
        let n = UPLOAD * UPLOAD * UPLOAD;
        let u = self.uniform_u16(value, voxel);
        let data = match self.eight_bit() && voxel == crate::VoxelType::U8 {
            true => BrickData::U8(vec![value as u8; n]),
            false => BrickData::U16(vec![u; n]),
        };
        BrickVoxels {
            data,
            range: [u, u],
            sub_ranges: [[u, u]; 8],
            constant: true,
            channels: Vec::new(),
            channel_ranges: Vec::new(),
            labels: Vec::new(),
        }
    }

    /// The normalised texel of voxel value `value` (of a store of type `voxel`): through
    /// [`BrickLevels::u8_table`] for 8-bit data, else over [`BrickLevels::range`] as the loaders
    /// normalise.
    fn uniform_u16(&self, value: f64, voxel: crate::VoxelType) -> u16 {
        if self.eight_bit() && voxel == crate::VoxelType::U8 {
            // The table's entry, made alone.
            return normalise(value as u8 as f64, self.range);
        }
        normalise(value, self.range)
    }

    /// Whether the pyramid's voxels are 8-bit (see [`BrickLevels::u8_table`]).
    fn eight_bit(&self) -> bool {
        match &self.sources[0] {
            LevelSource::Store(ms, _) => ms.voxel == crate::VoxelType::U8,
            LevelSource::Memory(v) => v.voxel_type() == crate::VoxelType::U8,
        }
    }

    /// For 8-bit data, the normalised value of each voxel value (what [`Volume::normalised_u16`]
    /// gives it over [`BrickLevels::range`]); `None` for wider data, normalised on the host.
    pub fn u8_table(&self) -> Option<[u16; 256]> {
        self.eight_bit()
            .then(|| std::array::from_fn(|v| normalise(v as f64, self.range)))
    }

    /// The floor of reading bricks: `keys` (chunks of the store's levels) decoded again plainly,
    /// in parallel on every core, each of rayon's tasks into one buffer it reuses for its
    /// chunks. Seconds, the decoding's CPU milliseconds summed over the threads (a buffer's
    /// allocation left out, as the loaders' spare buffers leave it out), and voxel bytes;
    /// nothing for levels in memory.
    pub fn plain_decode(&self, keys: &[crate::chunks::ChunkKey]) -> Result<(f64, f64, u64)> {
        use rayon::prelude::*;
        let start = std::time::Instant::now();
        let (cpu, bytes) = keys
            .par_iter()
            .map_init(
                || VoxelData::U8(Vec::new()),
                |buf, &(level, c)| -> Result<(f64, u64)> {
                    let LevelSource::Store(ms, l) = &self.sources[level] else {
                        return Ok((0.0, 0));
                    };
                    let info = &ms.levels[*l];
                    let lo: [usize; 3] = std::array::from_fn(|a| c[a] * info.chunk[a]);
                    let size: [usize; 3] =
                        std::array::from_fn(|a| info.chunk[a].min(info.dims[a] - lo[a]));
                    let n = size.iter().product();
                    buf.fit(ms.voxel, n);
                    let cpu = crate::chunks::thread_cpu_ms();
                    ms.read_box_into(*l, lo, size, buf)?;
                    let cpu = crate::chunks::thread_cpu_ms() - cpu;
                    Ok((cpu, buf.as_bytes().len() as u64))
                },
            )
            .try_reduce(|| (0.0, 0), |a, b| Ok((a.0 + b.0, a.1 + b.1)))?;
        Ok((start.elapsed().as_secs_f64(), cpu, bytes))
    }

    /// The edge along x, y, z of the cells level `level` is read in: its store's chunks, or a
    /// brick for a level in memory.
    pub fn grain(&self, level: usize) -> [usize; 3] {
        match &self.sources[level] {
            LevelSource::Store(ms, l) => ms.levels[*l].chunk.map(|c| c.max(1)),
            LevelSource::Memory(_) => [BRICK; 3],
        }
    }

    /// The decoded chunks the bricks are read from.
    pub fn chunks(&self) -> &ChunkCache {
        &self.chunks
    }

    /// Keeps about `bytes` of decoded chunks from now on (the cache starts empty again).
    pub fn set_chunk_budget(&mut self, bytes: u64) {
        self.chunks = ChunkCache::new(bytes);
    }

    /// The texels of brick `key` and its apron as the pool's slot holds them (x fastest): the
    /// CPU reference of what the GPU makes of [`BrickLevels::voxels`] (`passes::paging`).
    pub fn texels(&self, key: BrickKey) -> Result<Vec<u16>> {
        let voxels = self.voxels(key)?;
        let mut out = Vec::with_capacity(SLOT * SLOT * SLOT);
        self.extend_u16(&mut out, &voxels.data);
        Ok(out)
    }
}

/// `v` normalised to 0..=65535 over `[lo, hi]`, as [`Volume::normalised_u16_in`] maps it.
fn normalise(v: f64, range: [f64; 2]) -> u16 {
    crate::normalise::normalise_one(v, range[0], crate::normalise::scale_of(range))
}

/// Copies the part of `src` (placed at `src_lo` in the level) that overlaps `dst` (at `dst_lo`).
/// Fills the part of `dst` (at `dst_lo`) that the region `src_lo .. src_lo + dims` covers with
/// `value`'s one voxel (of `dst`'s type).
fn fill_box(
    value: &VoxelData,
    (src_lo, dims): ([usize; 3], [usize; 3]),
    dst: &mut Volume,
    dst_lo: [usize; 3],
) {
    let lo: [usize; 3] = std::array::from_fn(|a| src_lo[a].max(dst_lo[a]));
    let hi: [usize; 3] =
        std::array::from_fn(|a| (src_lo[a] + dims[a]).min(dst_lo[a] + dst.dims[a]));
    if (0..3).any(|a| lo[a] >= hi[a]) {
        return;
    }
    let dd = dst.dims;
    fn rows<T: Copy>(
        v: T,
        d: &mut [T],
        (lo, hi): ([usize; 3], [usize; 3]),
        dst_lo: [usize; 3],
        dd: [usize; 3],
    ) {
        for z in lo[2]..hi[2] {
            for y in lo[1]..hi[1] {
                let di = (lo[0] - dst_lo[0]) + dd[0] * ((y - dst_lo[1]) + dd[1] * (z - dst_lo[2]));
                d[di..di + (hi[0] - lo[0])].fill(v);
            }
        }
    }
    match (value, &mut dst.data) {
        (VoxelData::U8(s), VoxelData::U8(d)) => {
            s.first().map_or((), |&v| rows(v, d, (lo, hi), dst_lo, dd))
        }
        (VoxelData::U16(s), VoxelData::U16(d)) => {
            s.first().map_or((), |&v| rows(v, d, (lo, hi), dst_lo, dd))
        }
        (VoxelData::I16(s), VoxelData::I16(d)) => {
            s.first().map_or((), |&v| rows(v, d, (lo, hi), dst_lo, dd))
        }
        (VoxelData::F32(s), VoxelData::F32(d)) => {
            s.first().map_or((), |&v| rows(v, d, (lo, hi), dst_lo, dd))
        }
        // A store's levels share one type (`Multiscale::open` checks it).
        _ => {}
    }
}

/// How a brick's voxels become the texels that travel.
#[derive(Clone, Copy)]
enum Convert<'a> {
    /// Normalised to 16 bits over the range.
    Range([f64; 2]),
    /// 8-bit as they are; the GPU maps them through this table.
    Table(&'a [u16; 256]),
    /// Already normalised to 16 bits (chunks the cache keeps so): copied.
    Normalised,
}

/// The upload of a brick from its `inner` voxels (the box clamped into the level), `map` giving
/// for each of the [`UPLOAD`] positions per axis its index in `inner`, converted by `convert`.
/// Also the range of the slot's texels and whether all are one.
fn to_upload(inner: &Volume, map: &[Vec<usize>; 3], convert: Convert) -> BrickVoxels {
    let [lo, hi] = match convert {
        Convert::Range(r) => r,
        _ => [0.0, 1.0],
    };
    let scale = crate::normalise::scale_of([lo, hi]);
    // (By value, so that the loops keep the two in registers.)
    let norm = move |v: f64| crate::normalise::normalise_one(v, lo, scale);
    let mut stats = UploadStats::default();
    let d = inner.dims;
    let data = match (&inner.data, convert) {
        (VoxelData::U8(s), Convert::Table(t)) => {
            BrickData::U8(gather(d, map, s, |v| v, |v| t[v as usize], &mut stats))
        }
        (VoxelData::U16(s), Convert::Normalised) => {
            BrickData::U16(gather(d, map, s, |v| v, |v| v, &mut stats))
        }
        (VoxelData::U8(s), _) => BrickData::U16(gather(
            d,
            map,
            s,
            move |v| norm(v as f64),
            |v| v,
            &mut stats,
        )),
        (VoxelData::U16(s), _) => BrickData::U16(gather(
            d,
            map,
            s,
            move |v| norm(v as f64),
            |v| v,
            &mut stats,
        )),
        (VoxelData::I16(s), _) => BrickData::U16(gather(
            d,
            map,
            s,
            move |v| norm(v as f64),
            |v| v,
            &mut stats,
        )),
        (VoxelData::F32(s), _) => BrickData::U16(gather(
            d,
            map,
            s,
            move |v| norm(v as f64),
            |v| v,
            &mut stats,
        )),
    };
    stats.brick(data)
}

/// The rows or planes of an upload that trilinear samples inside the brick blend: its voxels and
/// one more on each side (the rest of the apron only the Sobel operator's fetches read).
const BLENDED: std::ops::Range<usize> = APRON - 1..UPLOAD + 1 - APRON;

/// The range of the texels trilinear samples inside the brick blend ([`BLENDED`]) in an upload
/// box of normalised values (x fastest), and whether the whole box holds one value.
fn box_stats(values: &[u16]) -> ([u16; 2], bool) {
    let first = values.first().copied().unwrap_or(0);
    let mut range = [u16::MAX, 0];
    let mut constant = true;
    for (i, &v) in values.iter().enumerate() {
        constant &= v == first;
        let (x, y, z) = (i % UPLOAD, (i / UPLOAD) % UPLOAD, i / (UPLOAD * UPLOAD));
        if [x, y, z].iter().all(|c| BLENDED.contains(c)) {
            range = [range[0].min(v), range[1].max(v)];
        }
    }
    (range, constant)
}

/// The range that holds every range of `ranges`.
fn union(ranges: &SubRanges) -> [u16; 2] {
    ranges
        .iter()
        .fold([u16::MAX, 0], |[lo, hi], r| [lo.min(r[0]), hi.max(r[1])])
}

/// The upload's rows or planes (x, y or z of the upload box) sub-block `q` (0 or 1) along an
/// axis takes: its voxels and one more on each side, `q·SUB − 1 ..= q·SUB + SUB` in the brick's
/// voxels, which are the upload's less [`APRON`].
fn sub_rows(q: usize) -> std::ops::RangeInclusive<usize> {
    q * SUB + APRON - 1..=q * SUB + SUB + APRON
}

/// What [`gather`] learns of a brick's normalised values on the way.
struct UploadStats {
    /// Per sub-block, the range of its texels (within the slot's: the upload less its outer
    /// layer).
    sub: SubRanges,
    /// Whether every value of the upload is the first.
    constant: bool,
}

impl UploadStats {
    /// The brick of upload `data`, which these stats measured.
    fn brick(self, data: BrickData) -> BrickVoxels {
        BrickVoxels {
            data,
            range: union(&self.sub),
            sub_ranges: self.sub,
            constant: self.constant,
            channels: Vec::new(),
            channel_ranges: Vec::new(),
            labels: Vec::new(),
        }
    }
}

impl Default for UploadStats {
    fn default() -> Self {
        UploadStats {
            sub: [[u16::MAX, 0]; 8],
            constant: true,
        }
    }
}

/// The [`UPLOAD`]³ voxels of `src` (of `dims`) at `map`'s indices, each turned by `convert` into
/// what travels, and `value` of that its normalised value, for `stats`: row by row, each row
/// converted and then measured in plain loops over slices without a branch per voxel (a brick's
/// rows are contiguous in the source except where the apron is clamped at the volume's faces).
fn gather<T: Copy, U: Copy>(
    dims: [usize; 3],
    map: &[Vec<usize>; 3],
    src: &[T],
    convert: impl Fn(T) -> U,
    value: impl Fn(U) -> u16,
    stats: &mut UploadStats,
) -> Vec<U> {
    let mut out = Vec::with_capacity(UPLOAD * UPLOAD * UPLOAD);
    let first = value(convert(
        src[map[0][0] + dims[0] * (map[1][0] + dims[1] * map[2][0])],
    ));
    let x0 = map[0][0];
    let contiguous = map[0].iter().enumerate().all(|(i, &x)| x == x0 + i);
    let mut same = true;
    for (z, &mz) in map[2].iter().enumerate() {
        for (y, &my) in map[1].iter().enumerate() {
            let row = &src[dims[0] * (my + dims[1] * mz)..];
            let start = out.len();
            match contiguous {
                true => out.extend(row[x0..x0 + UPLOAD].iter().map(|&v| convert(v))),
                false => out.extend(map[0].iter().map(|&x| convert(row[x]))),
            }
            row_stats(&out[start..], &value, (y, z), (first, &mut same), stats);
        }
    }
    stats.constant &= same;
    out
}

/// The upload of a brick read straight from `got`'s chunks (of `chunk` voxels, kept normalised
/// to 16 bits; [`BrickLevels::chunks_meeting`]), as [`to_upload`] makes it from the box pasted
/// out of them, but copied once: `at[a][i]` is the level's voxel along axis a of the upload's
/// i-th texel (clamped at the level's faces), and `uniform` the texel of a chunk of one value.
/// Each row is copied in runs, one per chunk it crosses, and measured as [`gather`] measures.
/// `None` where `got` is not what that needs (a chunk missing, or not kept as 16 bits).
fn gather_chunks(
    got: &[([usize; 3], Arc<Chunk>)],
    chunk: [usize; 3],
    at: &[Vec<usize>; 3],
    uniform: impl Fn(f64) -> u16,
) -> Option<BrickVoxels> {
    // The runs of a row: (texels, chunk along x, first voxel in that chunk).
    let mut runs: Vec<(usize, usize, usize)> = Vec::with_capacity(4);
    for &x in &at[0] {
        let (c, l) = (x / chunk[0], x % chunk[0]);
        match runs.last_mut() {
            Some(r) if r.1 == c && r.2 + r.0 == l => r.0 += 1,
            _ => runs.push((1, c, l)),
        }
    }
    let c0: [usize; 3] = std::array::from_fn(|a| at[a][0] / chunk[a]);
    let n: [usize; 3] = std::array::from_fn(|a| at[a][UPLOAD - 1] / chunk[a] - c0[a] + 1);
    // What each run reads in each row of chunks (y, z) the upload meets: found once here, not
    // once a row.
    let mut sources = vec![None; runs.len() * n[1] * n[2]];
    for (clo, k) in got {
        let c: [usize; 3] = std::array::from_fn(|a| (clo[a] / chunk[a]).wrapping_sub(c0[a]));
        if (0..3).any(|a| c[a] >= n[a]) {
            continue;
        }
        let source = match (k.value(), &k.volume.data) {
            (Some(v), _) => Source::Value(uniform(v)),
            (None, VoxelData::U16(src)) => Source::Voxels(src, k.dims),
            (None, _) => return None,
        };
        for (r, run) in runs.iter().enumerate() {
            if run.1 - c0[0] == c[0] {
                sources[r + runs.len() * (c[1] + n[1] * c[2])] = Some(source);
            }
        }
    }
    let mut out: Vec<u16> = Vec::with_capacity(UPLOAD * UPLOAD * UPLOAD);
    let mut stats = UploadStats::default();
    let mut same = true;
    let mut first = None;
    for (z, &gz) in at[2].iter().enumerate() {
        let (cz, lz) = (gz / chunk[2] - c0[2], gz % chunk[2]);
        for (y, &gy) in at[1].iter().enumerate() {
            let (cy, ly) = (gy / chunk[1] - c0[1], gy % chunk[1]);
            let row = &sources.get(runs.len() * (cy + n[1] * cz)..)?[..runs.len()];
            let start = out.len();
            for (&(len, _, lx), source) in runs.iter().zip(row) {
                match (*source)? {
                    Source::Value(v) => out.extend(std::iter::repeat_n(v, len)),
                    Source::Voxels(src, d) => {
                        let at = lx + d[0] * (ly + d[1] * lz);
                        out.extend_from_slice(src.get(at..at + len)?);
                    }
                }
            }
            let row = &out[start..];
            let f = *first.get_or_insert(row[0]);
            row_stats(row, &|v| v, (y, z), (f, &mut same), &mut stats);
        }
    }
    stats.constant &= same;
    Some(stats.brick(BrickData::U16(out)))
}

/// Where a run of [`gather_chunks`] reads its texels: a chunk of one value (that value
/// normalised) or a chunk's voxels (of these dims).
#[derive(Clone, Copy)]
enum Source<'a> {
    Value(u16),
    Voxels(&'a [u16], [usize; 3]),
}

/// Measures row `row` of an upload at (`y`, `z`), whose normalised values `value` gives, into
/// `stats`, and whether it holds `first` alone into `same` ([`gather`]'s measure).
fn row_stats<U: Copy>(
    row: &[U],
    value: &impl Fn(U) -> u16,
    (y, z): (usize, usize),
    (first, same): (u16, &mut bool),
    stats: &mut UploadStats,
) {
    // Once a row differs the brick is not constant, and later rows need not be looked at.
    if *same {
        *same = row.iter().fold(true, |s, &u| s & (value(u) == first));
    }
    if BLENDED.contains(&y) && BLENDED.contains(&z) {
        let range = |r: &[U]| {
            r.iter().fold([u16::MAX, 0], |[lo, hi], &u| {
                let v = value(u);
                [lo.min(v), hi.max(v)]
            })
        };
        let halves = [0, 1].map(|q| range(&row[sub_rows(q)]));
        for (i, r) in stats.sub.iter_mut().enumerate() {
            if sub_rows((i >> 1) & 1).contains(&y) && sub_rows(i >> 2).contains(&z) {
                let h = halves[i & 1];
                *r = [r[0].min(h[0]), r[1].max(h[1])];
            }
        }
    }
}

/// Which brick is in which pool slot, and the page table that says so to the shader.
pub struct BrickCache {
    capacity: usize,
    /// Slots held for good by the coarsest level (slots 0 .. pinned).
    pinned: usize,
    /// The coarsest level's first entry: entries from here on are pinned.
    pinned_from: usize,
    slot_of: HashMap<usize, usize>,
    owner: Vec<Option<usize>>,
    /// Per slot: it holds one constant value for every brick of that value ([`BrickVoxels`]'s
    /// `constant`), and is never evicted.
    shared: Vec<bool>,
    /// The slot of each constant value (with its channels') that has one.
    constant: HashMap<ConstantKey, usize>,
    last_used: Vec<u64>,
    clock: u64,
    /// Per page-table entry: its slot + 1, or 0 when the brick is not resident.
    pub page_table: Vec<u32>,
    /// Per page-table entry: the range of its slot's texels once it has been read, else
    /// [`UNKNOWN_RANGE`]; kept when the brick leaves, so that a frame can skip a brick it knows
    /// to be empty without reading it again.
    pub ranges: Vec<[u16; 2]>,
    /// Per page-table entry: its sub-blocks' ranges once it has been read, else
    /// [`UNKNOWN_SUB_RANGES`]; kept as `ranges` are.
    pub sub_ranges: Vec<SubRanges>,
    /// Bricks placed since the cache was made (uploaded, or sharing a constant slot).
    pub loaded: u64,
    /// Of those, bricks that shared a constant slot and uploaded nothing.
    pub shared_loads: u64,
    /// Bricks evicted since the cache was made.
    pub evicted: u64,
    /// The entries whose slot or range changed, in order (see [`BrickCache::changes`]).
    changes: Vec<usize>,
    /// Bumped each time `changes` is emptied.
    changes_epoch: u64,
}

/// The range of an entry whose brick has not been read yet.
pub const UNKNOWN_RANGE: [u16; 2] = [1, 0];

/// Constant slots at most, as a share of the pool: a slot per value beyond them would crowd out
/// the bricks that vary.
const CONSTANT_SHARE: usize = 8;

/// A brick the loaders read: its page-table entry, the range of its slot's texels and, when every
/// voxel of it has one value, that value.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Arrival {
    /// The brick's page-table entry.
    pub entry: usize,
    /// The range of its slot's normalised texels.
    pub range: [u16; 2],
    /// Its sub-blocks' ranges.
    pub sub_ranges: SubRanges,
    /// The value of every voxel, when the brick has one (with each mixed channel's after it).
    pub constant: Option<ConstantKey>,
}

/// Mixed channels a brick carries at most (`classify::channels::MAX_CHANNELS`).
pub const MAX_MIXED: usize = 8;

/// A brick of one value: that value, then each mixed channel's (0 past the last), then its one
/// segment index (0 without a label volume).
pub type ConstantKey = [u16; 2 + MAX_MIXED];

/// The key of a brick of `value` whose mixed channels hold `channels` and whose texels all
/// belong to segment index `label`.
pub fn constant_key(value: u16, channels: &[u16], label: u16) -> ConstantKey {
    std::array::from_fn(|i| match i {
        0 => value,
        i if i == 1 + MAX_MIXED => label,
        i => channels.get(i - 1).copied().unwrap_or(0),
    })
}

impl Arrival {
    /// What [`BrickCache::place`] needs of brick `entry`'s voxels.
    pub fn of(entry: usize, v: &BrickVoxels) -> Self {
        Arrival {
            entry,
            range: v.range,
            sub_ranges: v.sub_ranges,
            constant: v.constant.then(|| {
                let channels: Vec<u16> = v.channel_ranges.iter().map(|r| r[0]).collect();
                constant_key(
                    v.range[0],
                    &channels,
                    v.labels.first().copied().unwrap_or(0),
                )
            }),
        }
    }
}

/// Where [`BrickCache::place`] put a brick.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum Placement {
    /// In this slot, to be uploaded.
    Upload(usize),
    /// Sharing the constant slot of its value, already uploaded: nothing to upload.
    Shared(usize),
}

/// The smallest pool that works: the coarsest level and one more brick.
pub fn min_slots(levels: &BrickLevels) -> usize {
    levels.levels.last().map_or(0, PagedLevel::bricks) + 1
}

impl BrickCache {
    /// A cache of `capacity` slots for `levels`; refused in one sentence when that cannot hold
    /// the coarsest level and one more brick. The coarsest level's bricks are the first to load
    /// (see [`BrickCache::pinned_entries`]). Bricks whose value is known unread
    /// ([`BrickLevels::known_uniform`]) start with their ranges known.
    /// Each slot takes `slot_bytes` of the budget (for the sentence).
    pub fn new(
        levels: &BrickLevels,
        capacity: usize,
        (budget_mib, slot_bytes): (f64, usize),
    ) -> Result<Self> {
        let need = min_slots(levels);
        if capacity < need {
            return Err(Error::Invalid(format!(
                "a GPU budget of {} MiB holds {capacity} bricks; this volume needs at least {need}, so give `gpu_budget` {:.1} or more (its coarsest level and one more brick)",
                // As given (to the hundredth: 0.15 MiB is 0.1499996 once made bytes).
                format!("{budget_mib:.2}").trim_end_matches('0').trim_end_matches('.'),
                // Rounded up, so that the budget named holds them.
                ((need * slot_bytes) as f64 / (1 << 20) as f64 * 10.0).ceil() / 10.0
            )));
        }
        // Bricks whose value is known unread start with their ranges known, so that a frame
        // walks past the empty ones without asking for them.
        let known: Vec<Option<u16>> = (0..levels.entries())
            .map(|e| levels.key(e).and_then(|k| levels.known_uniform(k)))
            .collect();
        Ok(BrickCache {
            capacity,
            pinned: need - 1,
            pinned_from: levels.levels.last().map_or(0, |l| l.first),
            slot_of: HashMap::new(),
            owner: vec![None; capacity],
            shared: vec![false; capacity],
            constant: HashMap::new(),
            last_used: vec![0; capacity],
            clock: 1,
            page_table: vec![0; levels.entries()],
            ranges: known
                .iter()
                .map(|k| k.map_or(UNKNOWN_RANGE, |u| [u, u]))
                .collect(),
            sub_ranges: known
                .iter()
                .map(|k| k.map_or(UNKNOWN_SUB_RANGES, |u| [[u, u]; 8]))
                .collect(),
            loaded: 0,
            shared_loads: 0,
            evicted: 0,
            changes: Vec::new(),
            changes_epoch: 0,
        })
    }

    /// The entries whose slot or range changed since the log was last emptied, in order, with
    /// the log's epoch: a reader that keeps words made from the page table and the ranges
    /// remakes those of the entries past the last it read, or all of them when the epoch
    /// moved. (The log is emptied when it grows past one change per entry.)
    pub fn changes(&self) -> (u64, &[usize]) {
        (self.changes_epoch, &self.changes)
    }

    /// Slots in the pool.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Slots that no brick holds yet (outside the pinned ones): placing this many evicts nothing.
    pub fn free_slots(&self) -> usize {
        (self.pinned..self.capacity)
            .filter(|&s| !self.shared[s] && self.owner[s].is_none())
            .count()
    }

    /// Bricks resident now (those sharing a constant slot included).
    pub fn resident(&self) -> usize {
        self.slot_of.len()
    }

    /// Whether brick `entry` is resident.
    pub fn is_resident(&self, entry: usize) -> bool {
        self.page_table.get(entry).is_some_and(|&w| w != 0)
    }

    /// The finest level of `levels` with a resident brick.
    pub fn finest_resident(&self, levels: &BrickLevels) -> Option<usize> {
        self.slot_of
            .keys()
            .filter_map(|&e| levels.key(e))
            .map(|k| k.level)
            .min()
    }

    /// The coarsest level's entries: load these first; they are never evicted.
    pub fn pinned_entries(levels: &BrickLevels) -> Vec<usize> {
        let l = levels.levels.last().expect("a pyramid has a level");
        (l.first..l.first + l.bricks()).collect()
    }

    /// Gives slots to the bricks of `batch` that the loaders read: a brick of one value shares
    /// the slot of that value (uploaded once, never evicted; as many values as an eighth of the
    /// pool), any other takes a free slot or the least recently used one, never one placed in
    /// this batch nor a pinned one. The page table is updated at once (the caller uploads the
    /// bricks before the frame that reads it). `None` for a brick that found no slot.
    pub fn place(&mut self, batch: &[Arrival]) -> Vec<Option<Placement>> {
        self.clock += 1;
        if self.changes.len() > self.page_table.len() {
            self.changes.clear();
            self.changes_epoch += 1;
        }
        batch.iter().map(|a| self.place_one(a)).collect()
    }

    fn place_one(&mut self, a: &Arrival) -> Option<Placement> {
        let e = a.entry;
        if e >= self.page_table.len() {
            return None;
        }
        self.ranges[e] = a.range;
        self.sub_ranges[e] = a.sub_ranges;
        self.changes.push(e);
        if let Some(&s) = self.slot_of.get(&e) {
            self.last_used[s] = self.clock;
            return None;
        }
        let pinned = e >= self.pinned_from;
        if let (Some(v), false) = (a.constant, pinned) {
            if let Some(&s) = self.constant.get(&v) {
                self.assign(e, s);
                self.shared_loads += 1;
                return Some(Placement::Shared(s));
            }
        }
        let slot = self.free_or_victim(pinned)?;
        if let Some(old) = self.owner[slot].take() {
            self.slot_of.remove(&old);
            self.page_table[old] = 0;
            self.changes.push(old);
            self.evicted += 1;
        }
        let share = a
            .constant
            .filter(|_| !pinned && self.constant.len() < self.capacity / CONSTANT_SHARE);
        match share {
            Some(v) => {
                self.shared[slot] = true;
                self.constant.insert(v, slot);
            }
            None => self.owner[slot] = Some(e),
        }
        self.assign(e, slot);
        Some(Placement::Upload(slot))
    }

    fn assign(&mut self, e: usize, slot: usize) {
        self.slot_of.insert(e, slot);
        self.last_used[slot] = self.clock;
        self.page_table[e] = slot as u32 + 1;
        self.loaded += 1;
    }

    /// Whether a brick of these voxels would share the slot already made for its one value, and
    /// so upload nothing and evict nothing (the first brick of a value takes a slot of its own).
    pub fn shares_a_slot(&self, v: &BrickVoxels) -> bool {
        Arrival::of(0, v)
            .constant
            .is_some_and(|key| self.constant.contains_key(&key))
    }

    /// Marks the resident bricks of `entries` as used now: the last to be evicted.
    pub fn touch(&mut self, entries: &[usize]) {
        self.clock += 1;
        for e in entries {
            if let Some(&s) = self.slot_of.get(e) {
                self.last_used[s] = self.clock;
            }
        }
    }

    /// A free slot, or the least recently used one that was not placed or used in this batch
    /// (never a pinned one, nor one shared by a constant value).
    fn free_or_victim(&self, pinned: bool) -> Option<usize> {
        let range = match pinned {
            true => 0..self.pinned,
            false => self.pinned..self.capacity,
        };
        let open = |s: &usize| !self.shared[*s];
        range
            .clone()
            .filter(open)
            .find(|&s| self.owner[s].is_none())
            .or_else(|| {
                range
                    .filter(open)
                    .filter(|&s| self.last_used[s] < self.clock)
                    .min_by_key(|&s| self.last_used[s])
            })
    }
}

/// Per brick of `brick`³ voxels of `texels` (x fastest, `dims`), the (min, max) of the brick
/// widened by one voxel on every side, where a trilinear sample in the brick reads: the bricks'
/// counts along x, y, z and the ranges, x fastest.
pub fn widened_ranges(
    texels: &[u16],
    dims: [usize; 3],
    brick: usize,
) -> ([usize; 3], Vec<[u16; 2]>) {
    use rayon::prelude::*;
    let counts = dims.map(|d| d.div_ceil(brick));
    let range = (0..counts[0] * counts[1] * counts[2])
        .into_par_iter()
        .map(|b| {
            let c = [
                b % counts[0],
                (b / counts[0]) % counts[1],
                b / (counts[0] * counts[1]),
            ];
            let lo: [usize; 3] = std::array::from_fn(|a| (c[a] * brick).saturating_sub(1));
            let hi: [usize; 3] = std::array::from_fn(|a| ((c[a] + 1) * brick + 1).min(dims[a]));
            let (mut mn, mut mx) = (u16::MAX, 0u16);
            for z in lo[2]..hi[2] {
                for y in lo[1]..hi[1] {
                    let row = &texels[dims[0] * (y + dims[1] * z)..][lo[0]..hi[0]];
                    for &t in row {
                        mn = mn.min(t);
                        mx = mx.max(t);
                    }
                }
            }
            [mn, mx]
        })
        .collect();
    (counts, range)
}

mod nesting;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::phantom::shepp_logan;

    #[test]
    fn the_pyramid_ends_in_one_brick() {
        let levels = BrickLevels::of_volume(shepp_logan(100)).unwrap();
        let dims: Vec<[usize; 3]> = levels.levels().iter().map(|l| l.dims).collect();
        assert_eq!(dims, vec![[100; 3], [50; 3], [25; 3]]);
        assert_eq!(levels.levels()[0].counts, [4; 3]);
        assert_eq!(levels.entries(), 64 + 8 + 1);
        let key = BrickKey {
            level: 1,
            brick: [1, 0, 1],
        };
        assert_eq!(levels.key(levels.entry(key)), Some(key));
    }

    #[test]
    fn bricks_carry_their_levels_segment_indices() {
        // 70 x 40 x 40, id 5 where x >= 33 and id 9 where x < 33 (level 1: 35 x 20 x 20).
        let dims = [70, 40, 40];
        let ids: Vec<u8> = (0..70 * 40 * 40)
            .map(|i| if i % 70 >= 33 { 5 } else { 9 })
            .collect();
        let labels = crate::labels::Labels::of_volume(
            &Volume::new(dims, [1.0; 3], VoxelData::U8(ids)).unwrap(),
            "l",
        )
        .unwrap();
        let (five, nine) = (
            labels.index_of(5).unwrap() as u16,
            labels.index_of(9).unwrap() as u16,
        );
        let grey: Vec<u8> = (0..70 * 40 * 40).map(|i| (i % 251) as u8).collect();
        let mut levels =
            BrickLevels::of_volume(Volume::new(dims, [1.0; 3], VoxelData::U8(grey)).unwrap())
                .unwrap();
        let wrong = Arc::new(crate::labels::Labels {
            dims: [70, 40, 39],
            ..labels.clone()
        });
        let e = levels.set_labels(wrong, "m.nrrd").unwrap_err().to_string();
        assert!(
            e.starts_with("m.nrrd is 70 x 40 x 39") && e.contains("input's grid"),
            "{e}"
        );
        levels.set_labels(Arc::new(labels), "m.nrrd").unwrap();
        // Level 0, brick 1 along x: texel s holds voxel 30 + s; voxel 33 is the first of id 5.
        let key = BrickKey {
            level: 0,
            brick: [1, 0, 0],
        };
        let v = levels.voxels(key).unwrap();
        assert_eq!(v.labels.len(), SLOT * SLOT * SLOT);
        assert_eq!(&v.labels[..5], &[nine, nine, nine, five, five]);
        assert!(!v.constant);
        // Level 1, brick 0: texel s holds level-1 voxel s − 2 (clamped), level-0 voxels
        // 2 (s − 2) and one more: voxel 16 (32 and 33) holds one of each, the first met (9)
        // taken, so the first of id 5 is voxel 17, texel 19.
        let coarse = levels
            .voxels(BrickKey {
                level: 1,
                brick: [0; 3],
            })
            .unwrap();
        let row: Vec<u16> = coarse.labels[..SLOT].to_vec();
        assert!(row[..19].iter().all(|&i| i == nine), "{row:?}");
        assert!(row[19..].iter().all(|&i| i == five), "{row:?}");
        // One value with one segment shares a slot only with bricks of that segment.
        assert_ne!(constant_key(7, &[], five), constant_key(7, &[], nine));
    }

    #[test]
    fn brick_texels_are_the_in_core_texels() {
        let v = shepp_logan(40);
        let (texels, _) = v.normalised_u16();
        let levels = BrickLevels::of_volume(v).unwrap();
        let b = levels
            .texels(BrickKey {
                level: 0,
                brick: [1, 0, 0],
            })
            .unwrap();
        // Slot texel (x, y, z) is voxel (32 - 2 + x, y - 2, z - 2), clamped into the grid.
        let at = |x: usize, y: usize, z: usize| b[x + SLOT * (y + SLOT * z)];
        let voxel = |x: usize, y: usize, z: usize| texels[x + 40 * (y + 40 * z)];
        assert_eq!(at(2, 5, 9), voxel(32, 3, 7));
        assert_eq!(at(0, 0, 0), voxel(30, 0, 0));
        assert_eq!(at(1, 1, 1), voxel(31, 0, 0), "before the edge repeats it");
        assert_eq!(
            at(SLOT - 1, 20, 20),
            voxel(39, 18, 18),
            "past the edge repeats it"
        );
        assert_eq!(b.len(), SLOT * SLOT * SLOT);
    }

    /// The range, the sub-blocks' ranges and the one-value flag gathered row by row are those of the
    /// whole upload, at the volume's corner (where the apron is clamped), inside it and at its far edge.
    #[test]
    fn a_bricks_range_is_that_of_its_slot_texels() {
        // A ramp, whose smallest and largest slot texels lie on the slot's faces.
        let n = 80;
        let ramp = (0..n * n * n).map(|i| (i % n + 3 * (i / n % n) + 7 * (i / (n * n))) as f32);
        let ramp = Volume::new([n; 3], [1.0; 3], VoxelData::F32(ramp.collect())).unwrap();
        let mut seen = [false; 2];
        let pyramids = [shepp_logan(n), ramp].map(|v| BrickLevels::of_volume(v).unwrap());
        for brick in [[0, 0, 0], [1, 1, 1], [2, 1, 2], [1, 2, 0]] {
            for levels in &pyramids {
                let v = levels.voxels(BrickKey { level: 0, brick }).unwrap();
                let BrickData::U16(data) = &v.data else {
                    panic!("a float phantom travels as u16");
                };
                let (range, constant) = box_stats(data);
                assert_eq!((v.range, v.constant), (range, constant), "brick {brick:?}");
                // Each sub-block's range over its texels, counted out of the whole upload:
                // upload rows 1 ..= 18 for the lower half along an axis, 17 ..= 34 for the upper.
                let takes = |q: usize, u: usize| [1..=18, 17..=34][q].contains(&u);
                for (i, &got) in v.sub_ranges.iter().enumerate() {
                    let mut want = [u16::MAX, 0];
                    for (at, &u) in data.iter().enumerate() {
                        let c = [at % UPLOAD, at / UPLOAD % UPLOAD, at / (UPLOAD * UPLOAD)];
                        if (0..3).all(|a| takes((i >> a) & 1, c[a])) {
                            want = [want[0].min(u), want[1].max(u)];
                        }
                    }
                    assert_eq!(got, want, "brick {brick:?}, sub-block {i}");
                }
                seen[constant as usize] = true;
            }
        }
        assert_eq!(seen, [true, true], "bricks of one value and of many");
    }

    fn arrive(entry: usize) -> Arrival {
        Arrival {
            entry,
            range: [0, 9],
            sub_ranges: [[0, 9]; 8],
            constant: None,
        }
    }

    #[test]
    fn the_cache_pins_the_coarsest_level_and_evicts_the_least_recently_used() {
        let levels = BrickLevels::of_volume(shepp_logan(64)).unwrap();
        let refused = BrickCache::new(&levels, 1, (0.1, SLOT_BYTES))
            .err()
            .map(|e| e.to_string());
        assert!(
            refused
                .as_ref()
                .is_some_and(|e| e.contains("at least 2") && e.contains("`gpu_budget` 0.2")),
            "{refused:?}"
        );
        let mut cache = BrickCache::new(&levels, 3, (1.2, SLOT_BYTES)).unwrap();
        let pinned = BrickCache::pinned_entries(&levels);
        assert_eq!(pinned, vec![8]);
        let up = |s| Some(Placement::Upload(s));
        assert_eq!(cache.place(&[arrive(8)]), vec![up(0)]);
        assert_eq!(cache.free_slots(), 2, "the pinned slot is not counted");
        assert_eq!(cache.place(&[arrive(1), arrive(0)]), vec![up(1), up(2)]);
        assert_eq!(cache.free_slots(), 0);
        // Brick 1 used again, 2 new: 0 is the victim; then 3 replaces 1, never 8.
        cache.touch(&[1]);
        assert_eq!(cache.place(&[arrive(2)]), vec![up(2)]);
        assert_eq!(cache.place(&[arrive(3)]), vec![up(1)]);
        assert_eq!(cache.page_table[8], 1);
        assert_eq!(cache.page_table[0], 0);
        assert_eq!(cache.page_table[3], 2);
        assert_eq!((cache.loaded, cache.evicted), (5, 2));
        // Three at once into two evictable slots: the third finds none placed before it.
        let got = cache.place(&[arrive(4), arrive(5), arrive(6)]);
        assert_eq!(got.iter().filter(|p| p.is_some()).count(), 2);
        // A brick a frame read goes after one nobody read since.
        let (a, b) = (cache.page_table[4], cache.page_table[5]);
        assert!(a != 0 && b != 0);
        cache.touch(&[4]);
        assert_eq!(cache.place(&[arrive(7)]), vec![up(b as usize - 1)]);
        assert_eq!(cache.page_table[4], a, "the touched brick stays");
        assert_eq!(cache.ranges[7], [0, 9]);
        assert_eq!(cache.ranges[5], [0, 9], "a range outlives its brick");
        assert_eq!(
            cache.ranges[6],
            [0, 9],
            "known once read, with or without a slot"
        );
        assert_eq!(
            BrickCache::new(&levels, 3, (1.2, SLOT_BYTES))
                .unwrap()
                .ranges[0],
            UNKNOWN_RANGE
        );
    }

    /// The change log names every entry whose word or range changed: placed, evicted, or read
    /// again; and starts a new epoch once it outgrows the page table.
    #[test]
    fn the_cache_logs_the_entries_it_changes() {
        let levels = BrickLevels::of_volume(shepp_logan(64)).unwrap();
        let mut cache = BrickCache::new(&levels, 3, (1.2, SLOT_BYTES)).unwrap();
        cache.place(&[arrive(8), arrive(1), arrive(0)]);
        assert_eq!(cache.changes(), (0, &[8, 1, 0][..]));
        // 2 takes 1's slot (the least recently used), and 0 is read again where it is.
        cache.place(&[arrive(2)]);
        cache.place(&[arrive(0)]);
        assert_eq!(cache.changes().1[3..], [2, 1, 0]);
        assert_eq!(cache.page_table[1], 0);
        // Past one change per entry (9 here), the log empties into a new epoch.
        while cache.changes().1.len() <= cache.page_table.len() {
            cache.place(&[arrive(3)]);
        }
        assert_eq!(cache.changes().0, 0);
        cache.place(&[arrive(5)]);
        assert_eq!(cache.changes().0, 1);
        assert_eq!(cache.changes().1.first(), Some(&5));
    }

    #[test]
    fn bricks_of_one_value_share_a_slot() {
        let levels = BrickLevels::of_volume(shepp_logan(96)).unwrap();
        let mut cache = BrickCache::new(&levels, 16, (6.0, SLOT_BYTES)).unwrap();
        let flat = |entry, v| Arrival {
            entry,
            range: [v, v],
            sub_ranges: [[v, v]; 8],
            constant: Some(constant_key(v, &[], 0)),
        };
        let got = cache.place(&[flat(0, 7), flat(1, 7), flat(2, 8), arrive(3), flat(4, 7)]);
        let Some(Placement::Upload(s7)) = got[0] else {
            panic!("the first brick of a value is uploaded: {got:?}")
        };
        assert_eq!(got[1], Some(Placement::Shared(s7)));
        assert!(matches!(got[2], Some(Placement::Upload(s)) if s != s7));
        assert_eq!(got[4], Some(Placement::Shared(s7)));
        assert_eq!(cache.shared_loads, 2);
        // Shared slots are never victims: fill the rest of the pool many times over.
        for e in 5..60 {
            cache.place(&[arrive(e)]);
        }
        assert_eq!(cache.page_table[1], s7 as u32 + 1);
        assert_eq!(cache.page_table[0], s7 as u32 + 1);
    }

    #[test]
    fn the_level_read_for_the_range_is_not_read_again() {
        // 140³ is past RANGE_CHECK_VOXELS: the recorded range is checked on level 1 (70³),
        // which is then what a histogram of at most 2 Mi voxels asks for.
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.ome.zarr");
        let v = shepp_logan(140);
        crate::io::ome_zarr::write(&path, &v, &Default::default()).unwrap();
        let ms = Arc::new(Multiscale::open(&path).unwrap());
        let want = ms.read_level(1).unwrap();
        let levels = BrickLevels::of_store(ms, 1 << 26).unwrap();
        // Gone from the store: a second read would fail or read fill values.
        std::fs::remove_dir_all(path.join("1")).unwrap();
        let got = levels.read_small_level(RANGE_CHECK_VOXELS).unwrap();
        assert_eq!(got.dims, [70; 3]);
        assert_eq!(got.data, want.data);
        // A level not kept is read from the store.
        assert!(levels.read_small_level(1 << 12).is_ok());
    }

    /// `v` written as an OME-Zarr store of `chunk`³ chunks in a new temporary folder (kept alive
    /// by the first), and opened.
    fn store_of(v: &Volume, chunk: usize) -> (tempfile::TempDir, Arc<Multiscale>) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.ome.zarr");
        let opts = crate::io::ome_zarr::WriteOptions {
            chunk,
            ..Default::default()
        };
        crate::io::ome_zarr::write(&path, v, &opts).unwrap();
        let ms = Arc::new(Multiscale::open(&path).unwrap());
        (dir, ms)
    }

    #[test]
    fn brick_voxels_of_a_store_are_those_of_the_volume() {
        // A store's chunks are kept normalised to 16 bits; a volume in memory is normalised
        // brick by brick: the same texels, in every type.
        let f = shepp_logan(70);
        let typed = |t: crate::VoxelType| {
            let data = match t {
                crate::VoxelType::U16 => VoxelData::U16(
                    (0..f.len())
                        .map(|i| (f.data.get_f64(i) * 3000.0) as u16)
                        .collect(),
                ),
                crate::VoxelType::I16 => VoxelData::I16(
                    (0..f.len())
                        .map(|i| (f.data.get_f64(i) * 3000.0 - 1024.0) as i16)
                        .collect(),
                ),
                _ => f.data.clone(),
            };
            Volume::new(f.dims, f.spacing, data).unwrap()
        };
        use crate::VoxelType::{F32, I16, U16};
        for v in [F32, U16, I16].map(typed) {
            let (_dir, ms) = store_of(&v, 24);
            let from_store = BrickLevels::of_store(ms, 1 << 26).unwrap();
            let in_memory = BrickLevels::of_volume(v).unwrap();
            for brick in [[0, 0, 0], [1, 2, 1], [2, 2, 2]] {
                let key = BrickKey { level: 0, brick };
                let (a, b) = (
                    from_store.voxels(key).unwrap(),
                    in_memory.voxels(key).unwrap(),
                );
                assert_eq!(a.data, b.data, "{brick:?}");
                assert_eq!(a.range, b.range);
            }
            // The 12 chunks of level 0 the three bricks touch (8, 4 more, none more), each
            // decoded once however many bricks read it.
            let st = from_store.chunks().stats();
            assert_eq!((st.decoded, st.hits), (12, 1));
        }
    }

    /// Brick `key` of a store's pyramid as the loaders made it before `gather_chunks`: the box
    /// pasted out of its chunks, then gathered into the upload.
    fn pasted(levels: &BrickLevels, key: BrickKey) -> Option<BrickVoxels> {
        let LevelSource::Store(ms, l) = &levels.sources[key.level] else {
            return None;
        };
        let (inner_lo, size, lo) = levels.upload_box(key);
        let got = levels.chunks_meeting(ms, *l, inner_lo, size).unwrap();
        if let Some(v) = one_value_of(&got) {
            return Some(levels.uniform_brick(v, ms.voxel));
        }
        let inner = levels.paste_chunks(ms, *l, &got, inner_lo, size).unwrap();
        let dims = levels.levels[key.level].dims;
        let map = std::array::from_fn(|a| {
            let clamp = |v: i64| v.clamp(0, dims[a] as i64 - 1) as usize;
            (0..UPLOAD as i64)
                .map(|i| clamp(lo[a] + i) - inner_lo[a])
                .collect()
        });
        Some(to_upload(&inner, &map, Convert::Normalised))
    }

    #[test]
    fn bricks_gathered_from_chunks_are_those_pasted_from_them() {
        // Chunks of 24 and 16 (a brick's upload meets up to three along an axis, out of step
        // with the bricks), a level whose edge cuts bricks and chunks (70, then 35 and 18), and
        // chunks the writer left out (the phantom's empty corners): every brick of every level
        // read from the store (the smallest are kept in memory), voxels, ranges and all, is what
        // pasting its box and gathering from that made.
        let v = shepp_logan(70);
        for chunk in [24, 16] {
            let (_dir, ms) = store_of(&v, chunk);
            let levels = BrickLevels::of_store(ms, 1 << 26).unwrap();
            let mut many = 0;
            for e in 0..levels.entries() {
                let key = levels.key(e).unwrap();
                let Some(want) = pasted(&levels, key) else {
                    continue;
                };
                let got = levels.voxels(key).unwrap();
                assert_eq!(got.data, want.data, "{chunk}: {key:?}");
                assert_eq!(
                    (got.range, got.sub_ranges, got.constant),
                    (want.range, want.sub_ranges, want.constant),
                    "{chunk}: {key:?}"
                );
                many += usize::from(!got.constant);
            }
            assert!(many > 10, "{many} bricks of many values");
        }
    }

    #[test]
    fn bricks_known_unread_are_what_reading_them_gives() {
        // The phantom's corners are empty: the writer leaves out their chunks, and the bricks
        // that meet only those (their boxes within a chunk of twice their edge) hold the fill
        // value before anyone reads them.
        let v = shepp_logan(256);
        let u: Vec<u8> = (0..v.len())
            .map(|i| (v.data.get_f64(i) * 250.0) as u8)
            .collect();
        let bytes = Volume::new(v.dims, v.spacing, VoxelData::U8(u)).unwrap();
        for v in [v, bytes] {
            let (_dir, ms) = store_of(&v, 64);
            let absent = ms.absent_chunks(0).unwrap().unwrap();
            assert!(absent.count() > 0, "the writer left no chunk out");

            let mut levels = BrickLevels::of_store(ms, 1 << 26).unwrap();
            // A range below the fill value, so that it does not normalise to 0.
            levels.set_range([-0.5, levels.range[1]]);
            let (mut known, mut unknown) = (0, 0);
            for e in 0..levels.entries() {
                let key = levels.key(e).unwrap();
                let Some(u) = levels.known_uniform(key) else {
                    unknown += 1;
                    continue;
                };
                known += 1;
                let read = levels.voxels(key).unwrap();
                assert!(read.constant, "{key:?}");
                assert_eq!(
                    (read.range, read.sub_ranges),
                    ([u, u], [[u, u]; 8]),
                    "{key:?}"
                );
                assert!(u > 0 || levels.u8_table().is_some(), "{key:?}");
            }
            assert!(known > 0 && unknown > 0, "{known} known, {unknown} not");
            // The cache starts with those ranges, and no other.
            let cache = BrickCache::new(&levels, 64, (1.0, SLOT_BYTES)).unwrap();
            let starts_known = cache.ranges.iter().filter(|r| **r != UNKNOWN_RANGE).count();
            assert_eq!(starts_known, known);
        }
    }

    #[test]
    fn a_chunk_gone_from_the_store_after_it_was_opened_is_named() {
        // A store in chunks of 32³: the phantom's middle chunks hold voxels, and reading a brick
        // there after its chunk file went reads the fill value, which must not be drawn as air.
        let v = shepp_logan(128);
        let (dir, ms) = store_of(&v, 32);
        let levels = BrickLevels::of_store(ms.clone(), 1 << 26).unwrap();
        let key = BrickKey {
            level: 0,
            brick: [2, 2, 2],
        };
        let before = levels.voxels(key).unwrap();
        assert!(!before.constant, "the middle brick holds the phantom");
        let chunk = dir.path().join("s.ome.zarr/0/c/2/2/2");
        std::fs::remove_file(&chunk).unwrap();
        // The cache still holds the chunk: the brick reads as before.
        assert_eq!(levels.voxels(key).unwrap().data, before.data);
        let fresh = BrickLevels::of_store(ms.clone(), 1 << 26).unwrap();
        assert!(
            fresh.voxels(key).unwrap().data != before.data,
            "opened without it: fill"
        );
        // Read anew (the cache emptied), the brick's chunk is missed and named.
        let mut levels = levels;
        levels.set_chunk_budget(DEFAULT_CHUNK_CACHE);
        let e = levels
            .voxels(key)
            .map(|_| ())
            .expect_err("a chunk gone")
            .to_string();
        assert!(
            e.contains("chunk 0/c/2/2/2 of level 0") && e.contains("gone"),
            "{e}"
        );
    }

    #[test]
    fn bricks_inside_chunks_of_one_value_are_those_of_the_volume() {
        // A volume of one value with a ball in a corner: most chunks hold one value, a brick's
        // box touches several, and some bricks straddle the ball's chunks.
        let n = 80usize;
        let f: Vec<f32> = (0..n * n * n)
            .map(|i| {
                let p = [i % n, (i / n) % n, i / (n * n)].map(|c| c as f32 - 66.0);
                if p.iter().map(|c| c * c).sum::<f32>() < 100.0 {
                    0.9
                } else {
                    0.3
                }
            })
            .collect();
        let u: Vec<u8> = f.iter().map(|&v| (v * 200.0) as u8).collect();
        for data in [VoxelData::F32(f), VoxelData::U8(u)] {
            let v = Volume::new([n; 3], [1.0; 3], data).unwrap();
            let (_dir, ms) = store_of(&v, 20);
            let mut from_store = BrickLevels::of_store(ms, 1 << 26).unwrap();
            let mut in_memory = BrickLevels::of_volume(v).unwrap();
            // The same range for both (the store's comes from its scan), not starting at 0.
            from_store.set_range([0.1, 200.0 * 0.95]);
            in_memory.set_range(from_store.range);
            let (mut uniform, mut varied) = (0, 0);
            // Level 0: the coarser levels of a store are the writer's, not the pyramid's.
            let counts = from_store.levels()[0].counts;
            for i in 0..counts.iter().product::<usize>() {
                let brick = [
                    i % counts[0],
                    (i / counts[0]) % counts[1],
                    i / (counts[0] * counts[1]),
                ];
                let key = BrickKey { level: 0, brick };
                let (a, b) = (
                    from_store.voxels(key).unwrap(),
                    in_memory.voxels(key).unwrap(),
                );
                assert_eq!(a.data, b.data, "{key:?}");
                assert_eq!((a.range, a.constant), (b.range, b.constant), "{key:?}");
                if a.constant {
                    uniform += 1
                } else {
                    varied += 1
                }
            }
            assert!(
                uniform > 0 && varied > 0,
                "{uniform} uniform, {varied} varied"
            );
        }
    }
}
