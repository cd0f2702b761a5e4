//! The host side of the brick cache (issue 26): a volume as a pyramid of fixed-size bricks, the
//! bricks' texels as the renderer samples them, and which brick sits in which slot of the GPU's
//! pool. Nothing here knows about Vulkan; `passes::paging` owns the pool images and records the
//! uploads.
//!
//! ## Layout
//! Every level is cut into bricks of [`BRICK`]³ voxels. A pool slot holds a brick with a one-voxel
//! apron on every side ([`SLOT`]³ texels), so trilinear filtering anywhere inside the brick reads
//! only its own slot. Voxels outside the level repeat its nearest edge voxel, as a clamp-to-edge
//! sampler does, so a bricked sample equals the in-core sample at every position.
//!
//! The pyramid is the store's levels (or, for a volume in memory, the volume itself), continued by
//! 2×2×2 means in memory until the coarsest level is one brick: that level is always resident, so
//! every sample has something to fall back to.
//!
//! ## Texels
//! Intensities are normalised to u16 over level 0's value range, exactly as
//! [`Volume::normalised_u16`] does for the in-core texture, and gradients are the in-core
//! `sobel_normals` pass's Sobel operator (borders clamp) on those normalised values, as
//! half-floats: the pool holds what the in-core textures hold, brick by brick.
//!
//! ## Slots
//! [`BrickCache`] hands out slots: the coarsest level's first and for good, then the bricks a
//! frame asks for most, evicting the least recently used bricks no ray asked for this time
//! (used: loaded, or read by a frame that said so, [`BrickCache::touch`]).

use crate::error::{Error, Result};
use crate::volume::io::ome_zarr::Multiscale;
use crate::volume::source::{read_box_clamped, BoxSource};
use crate::volume::Volume;
use std::collections::HashMap;
use std::sync::Arc;

/// Edge of a brick in voxels.
pub const BRICK: usize = 32;
/// Apron voxels on each side of a brick in its slot.
pub const APRON: usize = 1;
/// Edge of a pool slot in texels.
pub const SLOT: usize = BRICK + 2 * APRON;
/// Bytes a voxel takes in the renderer's textures: R16 intensity and RGBA16F gradient.
pub const TEXTURE_BYTES_PER_VOXEL: u64 = 2 + 8;
/// Bytes of one slot.
pub const SLOT_BYTES: usize = SLOT * SLOT * SLOT * TEXTURE_BYTES_PER_VOXEL as usize;

/// Bytes the renderer's textures of a volume of `dims` take in core.
pub fn in_core_bytes(dims: [usize; 3]) -> u64 {
    dims.iter().map(|&n| n as u64).product::<u64>() * TEXTURE_BYTES_PER_VOXEL
}
/// Most levels a pyramid may have (the page table's header has room for this many).
pub const MAX_LEVELS: usize = 16;

/// One level as the cache sees it.
#[derive(Clone, Debug, PartialEq)]
pub struct PagedLevel {
    pub dims: [usize; 3],
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
    pub level: usize,
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

/// The texels of one brick and its apron, as the pool's slot holds them (x fastest).
pub struct BrickTexels {
    pub intensity: Vec<u16>,
    /// Gradient xyz and its length, as half-float bits.
    pub gradient: Vec<[u16; 4]>,
}

/// A volume as a pyramid of bricks, read brick by brick.
pub struct BrickLevels {
    levels: Vec<PagedLevel>,
    sources: Vec<LevelSource>,
    /// Data values that map to normalised 0 and 1.
    pub range: [f64; 2],
    /// Level 0's placement (origin; a store has no directions).
    pub geometry: crate::volume::geometry::Geometry,
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
    /// taken from level 0 when that is at most `scan_limit` voxels, else from its coarsest level
    /// (said once at run time: extremes thinner than that level's voxels are then clipped).
    pub fn of_store(ms: Arc<Multiscale>, scan_limit: usize) -> Result<Self> {
        let range = match ms.range {
            Some(r) => r,
            None => {
                let level0: usize = ms.levels[0].dims.iter().product();
                let pick = if level0 <= scan_limit {
                    0
                } else {
                    ms.levels.len() - 1
                };
                if pick > 0 {
                    log::warn!(
                        "{} does not record its value range; taking it from level {pick}, so extremes finer than that level may be clipped",
                        ms.root.display()
                    );
                }
                ms.read_level(pick)?.normalised_range()
            }
        };
        let geometry = crate::volume::geometry::Geometry {
            origin: ms.levels[0].origin,
            ..Default::default()
        };
        let sources = (0..ms.levels.len())
            .map(|l| LevelSource::Store(ms.clone(), l))
            .collect();
        Self::build(sources, range, geometry)
    }

    fn build(
        mut sources: Vec<LevelSource>,
        range: [f64; 2],
        geometry: crate::volume::geometry::Geometry,
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
                sources.push(LevelSource::Memory(crate::volume::io::ome_zarr::halve(
                    &whole,
                )?));
            }
            if levels.len() > MAX_LEVELS {
                return Err(Error::Invalid(format!(
                    "the volume needs more than {MAX_LEVELS} levels to reach one brick"
                )));
            }
        }
        Ok(BrickLevels {
            levels,
            sources,
            range,
            geometry,
        })
    }

    /// The pyramid of the store at `path` when `path` is a store whose in-core textures exceed
    /// `budget` bytes; `None` when it is not a store or fits (level 0 is never read here).
    pub fn of_store_beyond(path: &std::path::Path, budget: u64) -> Result<Option<Self>> {
        use crate::volume::io::ome_zarr;
        if !ome_zarr::is_store(path) {
            return Ok(None);
        }
        let ms = ome_zarr::Multiscale::open(path)?;
        if in_core_bytes(ms.levels[0].dims) <= budget {
            return Ok(None);
        }
        // Level 0 is read whole for the range only when it is small (64 Mi voxels).
        Ok(Some(Self::of_store(Arc::new(ms), 1 << 26)?))
    }

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
        let dims = self.levels[i].dims;
        self.sources[i].source()?.read_box([0; 3], dims)
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

    /// The texels of brick `key` and its apron.
    pub fn texels(&self, key: BrickKey) -> Result<BrickTexels> {
        let level = &self.levels[key.level];
        let src = self.sources[key.level].source()?;
        // The slot's texels and one more voxel on every side, which the Sobel operator reads.
        let lo: [i64; 3] =
            std::array::from_fn(|a| (key.brick[a] * BRICK) as i64 - APRON as i64 - 1);
        let n = SLOT + 2;
        let values = read_box_clamped(&*src, lo, [n; 3])?;
        let [lo_v, hi_v] = self.range;
        let scale = if hi_v > lo_v {
            65535.0 / (hi_v - lo_v)
        } else {
            0.0
        };
        let norm: Vec<u16> = values
            .iter()
            .map(|&v| ((v as f64 - lo_v) * scale).round().clamp(0.0, 65535.0) as u16)
            .collect();
        let dims = level.dims;
        // A texel outside the level takes the gradient of the edge voxel it repeats.
        let at = |g: [i64; 3]| -> f32 {
            let c: [i64; 3] = std::array::from_fn(|a| g[a].clamp(0, dims[a] as i64 - 1) - lo[a]);
            norm[c[0] as usize + n * (c[1] as usize + n * c[2] as usize)] as f32 / 65535.0
        };
        let inv = level.spacing.map(|s| (1.0 / s) as f32);
        let mut intensity = Vec::with_capacity(SLOT * SLOT * SLOT);
        let mut gradient = Vec::with_capacity(SLOT * SLOT * SLOT);
        for z in 0..SLOT {
            for y in 0..SLOT {
                for x in 0..SLOT {
                    let g = [x, y, z].map(|v| v as i64 + 1);
                    let global: [i64; 3] = std::array::from_fn(|a| lo[a] + g[a]);
                    intensity.push(norm[(g[0] + n as i64 * (g[1] + n as i64 * g[2])) as usize]);
                    let c: [i64; 3] =
                        std::array::from_fn(|a| global[a].clamp(0, dims[a] as i64 - 1));
                    gradient.push(sobel(&at, c, inv));
                }
            }
        }
        Ok(BrickTexels {
            intensity,
            gradient,
        })
    }
}

/// The 3D Sobel gradient at voxel `c` of `at` (neighbours clamped by `at`), per unit of spacing,
/// and its length, as half-float bits: `render/sobel_normals.comp` on the host.
fn sobel(at: &dyn Fn([i64; 3]) -> f32, c: [i64; 3], inv_spacing: [f32; 3]) -> [u16; 4] {
    let mut g = [0f32; 3];
    for dz in -1i64..=1 {
        for dy in -1i64..=1 {
            for dx in -1i64..=1 {
                let v = at([c[0] + dx, c[1] + dy, c[2] + dz]);
                let w = [2 - dx.abs(), 2 - dy.abs(), 2 - dz.abs()].map(|w| w as f32);
                g[0] += v * dx as f32 * w[1] * w[2];
                g[1] += v * dy as f32 * w[0] * w[2];
                g[2] += v * dz as f32 * w[0] * w[1];
            }
        }
    }
    let g: [f32; 3] = std::array::from_fn(|a| g[a] * inv_spacing[a] / 32.0);
    let len = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
    [g[0], g[1], g[2], len].map(|v| half::f16::from_f32(v).to_bits())
}

/// Which brick is in which pool slot, and the page table that says so to the shader.
pub struct BrickCache {
    capacity: usize,
    /// Slots held for good by the coarsest level.
    pinned: usize,
    slot_of: HashMap<usize, usize>,
    owner: Vec<Option<usize>>,
    last_used: Vec<u64>,
    clock: u64,
    /// Per page-table entry: its slot + 1, or 0 when the brick is not resident.
    pub page_table: Vec<u32>,
    /// Bricks loaded since the cache was made.
    pub loaded: u64,
    /// Bricks evicted since the cache was made.
    pub evicted: u64,
}

/// The smallest pool that works: the coarsest level and one more brick.
pub fn min_slots(levels: &BrickLevels) -> usize {
    levels.levels.last().map_or(0, PagedLevel::bricks) + 1
}

impl BrickCache {
    /// A cache of `capacity` slots for `levels`; refused in one sentence when that cannot hold
    /// the coarsest level and one more brick. The coarsest level's bricks are the first to load
    /// (see [`BrickCache::pinned_entries`]).
    pub fn new(levels: &BrickLevels, capacity: usize, budget_mib: f64) -> Result<Self> {
        let need = min_slots(levels);
        if capacity < need {
            return Err(Error::Invalid(format!(
                "a GPU budget of {budget_mib} MiB holds {capacity} bricks; this volume needs at least {need} ({:.1} MiB: its coarsest level and one more brick)",
                (need * SLOT_BYTES) as f64 / (1 << 20) as f64
            )));
        }
        Ok(BrickCache {
            capacity,
            pinned: need - 1,
            slot_of: HashMap::new(),
            owner: vec![None; capacity],
            last_used: vec![0; capacity],
            clock: 1,
            page_table: vec![0; levels.entries()],
            loaded: 0,
            evicted: 0,
        })
    }

    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Bricks resident now.
    pub fn resident(&self) -> usize {
        self.slot_of.len()
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

    /// Decides which of the `wanted` entries (with how many rays asked for each) to load now,
    /// at most `max` of them, most asked first: into free slots, else in place of the least
    /// recently used bricks nobody asked for this time. The page table is updated at once (the
    /// caller uploads the bricks before the frame that reads it). Returns (entry, slot) pairs.
    pub fn plan(&mut self, wanted: &[(usize, u32)], max: usize) -> Vec<(usize, usize)> {
        self.clock += 1;
        let mut order: Vec<(usize, u32)> = wanted.to_vec();
        order.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
        for (e, _) in &order {
            if let Some(&s) = self.slot_of.get(e) {
                self.last_used[s] = self.clock;
            }
        }
        let mut loads = Vec::new();
        for (e, _) in order {
            if loads.len() == max {
                break;
            }
            if self.slot_of.contains_key(&e) || e >= self.page_table.len() {
                continue;
            }
            let Some(slot) = self.free_or_victim() else {
                break;
            };
            if let Some(old) = self.owner[slot].take() {
                self.slot_of.remove(&old);
                self.page_table[old] = 0;
                self.evicted += 1;
            }
            self.owner[slot] = Some(e);
            self.slot_of.insert(e, slot);
            self.last_used[slot] = self.clock;
            self.page_table[e] = slot as u32 + 1;
            self.loaded += 1;
            loads.push((e, slot));
        }
        loads
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

    /// A free slot, or the least recently used one that was not asked for this time (never a
    /// pinned one).
    fn free_or_victim(&self) -> Option<usize> {
        let range = if self.slot_of.len() < self.pinned {
            0..self.pinned
        } else {
            self.pinned..self.capacity
        };
        let slots = || range.clone();
        slots().find(|&s| self.owner[s].is_none()).or_else(|| {
            slots()
                .filter(|&s| self.last_used[s] < self.clock)
                .min_by_key(|&s| self.last_used[s])
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::volume::phantom::shepp_logan;

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
        // Slot texel (x, y, z) is voxel (32 - 1 + x, y - 1, z - 1), clamped into the grid.
        let at = |x: usize, y: usize, z: usize| b.intensity[x + SLOT * (y + SLOT * z)];
        let voxel = |x: usize, y: usize, z: usize| texels[x + 40 * (y + 40 * z)];
        assert_eq!(at(1, 5, 9), voxel(32, 4, 8));
        assert_eq!(at(0, 0, 0), voxel(31, 0, 0));
        assert_eq!(
            at(SLOT - 1, 20, 20),
            voxel(39, 19, 19),
            "past the edge repeats it"
        );
        // The gradient of a voxel past the edge is the edge voxel's.
        let g = |x: usize| b.gradient[x + SLOT * (20 + SLOT * 20)];
        assert_eq!(g(8), g(SLOT - 1));
        assert_ne!(b.gradient.iter().filter(|g| g[3] != 0).count(), 0);
    }

    #[test]
    fn the_cache_pins_the_coarsest_level_and_evicts_the_least_recently_used() {
        let levels = BrickLevels::of_volume(shepp_logan(64)).unwrap();
        let refused = BrickCache::new(&levels, 1, 0.4)
            .err()
            .map(|e| e.to_string());
        assert!(refused.is_some_and(|e| e.contains("at least 2")));
        let mut cache = BrickCache::new(&levels, 3, 1.2).unwrap();
        let pinned = BrickCache::pinned_entries(&levels);
        assert_eq!(pinned, vec![8]);
        assert_eq!(cache.plan(&[(8, 1)], 8), vec![(8, 0)]);
        assert_eq!(cache.plan(&[(0, 5), (1, 9)], 8), vec![(1, 1), (0, 2)]);
        // Brick 1 asked for again, 2 new: 0 is the victim; then 3 replaces 1, never 8.
        assert_eq!(cache.plan(&[(1, 1), (2, 1)], 8), vec![(2, 2)]);
        assert_eq!(cache.plan(&[(3, 1)], 8), vec![(3, 1)]);
        assert_eq!(cache.page_table[8], 1);
        assert_eq!(cache.page_table[0], 0);
        assert_eq!(cache.page_table[3], 2);
        assert_eq!((cache.loaded, cache.evicted), (5, 2));
        // Everything asked for at once: only what fits this time.
        assert_eq!(cache.plan(&[(4, 1), (5, 1), (6, 1)], 8).len(), 2);
        // A brick a frame read goes after one nobody read since.
        let (a, b) = (cache.page_table[4], cache.page_table[5]);
        assert!(a != 0 && b != 0);
        cache.touch(&[4]);
        assert_eq!(cache.plan(&[(7, 1)], 8), vec![(7, b as usize - 1)]);
        assert_eq!(cache.page_table[4], a, "the touched brick stays");
    }
}
