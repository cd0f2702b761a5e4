//! How the bricks of a pyramid's levels nest, as the ray caster's lookup sees them: which brick
//! of a coarser level holds every sample of a finer brick, and which finer bricks a coarse one
//! overlaps. A missing brick's page-table word names the finest resident coarser brick that
//! holds it whole, so that the ray caster's walk over the coarser levels for its samples starts
//! there and ends at its first step; when a brick comes or goes, the words of the finer bricks
//! it overlaps are made again.
//!
//! The lookup of level l places texture coordinate t (clamped into [0, 1]) at voxel
//! v = t · scale_l ([`BrickLevels::texture_scale`], in f32) and in brick ⌊v / 32⌋, clamped into
//! the level's bricks. Where two levels' scales are a power of two apart in f32, a finer brick's
//! samples land in exactly one coarser brick, found by the same arithmetic; otherwise a brick is
//! held only with a margin ([`MARGIN`]) far larger than f32's rounding.

use super::{BrickKey, BrickLevels, BRICK};

/// How far, in bricks of the coarser level, a finer brick's ends must stay from a coarser
/// brick's boundary to count as inside it, where the two levels' scales are not a power of two
/// apart (f32 places a voxel of a 2048-voxel level within about 10⁻⁵ bricks).
const MARGIN: f64 = 1e-3;

impl BrickLevels {
    /// Level `level`'s voxels per unit of texture coordinate along x, y and z, as the ray
    /// caster's page-table header gives them (level 0's extent over the level's voxel, in f32).
    pub fn texture_scale(&self, level: usize) -> [f32; 3] {
        let (l0, l) = (&self.levels[0], &self.levels[level]);
        std::array::from_fn(|a| (l0.dims[a] as f64 * l0.spacing[a] / l.spacing[a]) as f32)
    }

    /// The brick of level `coarse` in which the ray caster's lookup places every sample that it
    /// places in brick `key` (of a finer level), or `None` when those samples may fall in more
    /// than one.
    pub fn holder(&self, key: BrickKey, coarse: usize) -> Option<[usize; 3]> {
        let axes = self.axes(key.level, coarse);
        let mut held = [0; 3];
        for a in 0..3 {
            held[a] = axes[a].holder(key.brick[a])?;
        }
        Some(held)
    }

    /// The page-table entries of the levels finer than `key`'s whose bricks overlap brick
    /// `key` (a few more at the margins, never fewer), the coarser levels' first.
    pub fn finer_overlapping(&self, key: BrickKey) -> Vec<usize> {
        let mut out = Vec::new();
        for level in (0..key.level).rev() {
            let axes = self.axes(level, key.level);
            let span: [(usize, usize); 3] =
                std::array::from_fn(|a| axes[a].overlapping(key.brick[a]));
            for z in span[2].0..=span[2].1 {
                for y in span[1].0..=span[1].1 {
                    for x in span[0].0..=span[0].1 {
                        out.push(self.entry(BrickKey {
                            level,
                            brick: [x, y, z],
                        }));
                    }
                }
            }
        }
        out
    }

    /// Levels `fine` and `coarse` along x, y and z: from [`Nesting`], made with the pyramid (a
    /// page table's words ask for them at each of a 2048³ store's 300,000 entries).
    fn axes(&self, fine: usize, coarse: usize) -> [Axis; 3] {
        match self.nesting.pairs.get(fine * self.nesting.levels + coarse) {
            Some(a) => *a,
            None => self.axes_made(fine, coarse),
        }
    }

    /// [`BrickLevels::axes`], made from the levels' scales and brick counts.
    fn axes_made(&self, fine: usize, coarse: usize) -> [Axis; 3] {
        let (f, c) = (self.texture_scale(fine), self.texture_scale(coarse));
        std::array::from_fn(|a| {
            let counts = [self.levels[fine].counts[a], self.levels[coarse].counts[a]];
            Axis::new(f[a] as f64, c[a] as f64, counts)
        })
    }
}

/// Every pair of a pyramid's levels along x, y and z ([`BrickLevels::axes`]), made once.
#[derive(Default)]
pub(super) struct Nesting {
    levels: usize,
    /// Per pair (finer, coarser), at finer · levels + coarser.
    pairs: Vec<[Axis; 3]>,
}

impl Nesting {
    /// The pairs of `levels`' levels.
    pub(super) fn of(levels: &BrickLevels) -> Self {
        let n = levels.levels.len();
        let pairs = (0..n * n).map(|i| levels.axes_made(i / n, i % n)).collect();
        Nesting { levels: n, pairs }
    }
}

/// One axis of a finer level and a coarser one: their scales (f32 values) and brick counts, and
/// whether the coarser scale is the finer one over a power of two, exactly: then a voxel's
/// coordinate in the coarser level is the finer one's scaled by that power, with no rounding.
#[derive(Copy, Clone)]
struct Axis {
    fine: f64,
    coarse: f64,
    counts: usize,
    coarse_counts: usize,
    exact: bool,
    /// With `exact`, that power of two's exponent.
    shift: u32,
}

impl Axis {
    /// The axis of scales `fine` and `coarse` (f32 values) and `counts` bricks (finer, coarser).
    fn new(fine: f64, coarse: f64, [counts, coarse_counts]: [usize; 2]) -> Self {
        let k = (fine / coarse).log2().round();
        let exact = k >= 0.0 && coarse * 2f64.powi(k as i32) == fine;
        Axis {
            fine,
            coarse,
            counts,
            coarse_counts,
            exact,
            shift: if exact { k as u32 } else { 0 },
        }
    }

    /// The voxels of the finer level whose samples the lookup places in brick `b`: from 32 b
    /// to 32 (b + 1), or to the level's scale for the last brick, which takes every sample up to
    /// t = 1 (the lookup clamps t into [0, 1]).
    fn fine_voxels(&self, b: usize) -> (f64, f64) {
        let edge = BRICK as f64;
        let hi = if b + 1 >= self.counts {
            self.fine
        } else {
            (b + 1) as f64 * edge
        };
        (b as f64 * edge, hi)
    }

    fn clamp(&self, brick: f64) -> usize {
        (brick.max(0.0) as usize).min(self.coarse_counts - 1)
    }

    /// The coarser brick that holds finer brick `b` on this axis, if one does.
    fn holder(&self, b: usize) -> Option<usize> {
        if self.exact && b + 1 < self.counts {
            // What the arithmetic below gives there: the first and last coarser voxel are
            // ⌊32 b / 2^k⌋ and ⌈32 (b + 1) / 2^k⌉ - 1, in one brick, b >> k.
            return Some((b >> self.shift).min(self.coarse_counts - 1));
        }
        self.holder_by_voxels(b)
    }

    /// [`Axis::holder`] from the finer brick's voxels scaled into the coarser level.
    fn holder_by_voxels(&self, b: usize) -> Option<usize> {
        let (lo, hi) = self.fine_voxels(b);
        let r = self.coarse / self.fine / BRICK as f64;
        let (x_lo, x_hi) = (lo * r, hi * r);
        let last = b + 1 >= self.counts;
        let first = if b == 0 || self.exact {
            x_lo.floor()
        } else {
            (x_lo - MARGIN).floor()
        };
        // The finer brick's samples stop short of `hi`, except the last brick's, which reach it.
        let end = if !last && self.exact {
            x_hi.ceil() - 1.0
        } else {
            (x_hi + MARGIN).floor()
        };
        let (first, end) = (self.clamp(first), self.clamp(end));
        (first == end).then_some(first)
    }

    /// The finer bricks that overlap coarser brick `c` on this axis (first and last), with the
    /// margin on both sides unless the scales are a power of two apart.
    fn overlapping(&self, c: usize) -> (usize, usize) {
        let edge = BRICK as f64;
        let r = self.fine / self.coarse / edge;
        let lo = if c == 0 { 0.0 } else { c as f64 * edge * r };
        let hi = if c + 1 >= self.coarse_counts {
            f64::INFINITY
        } else {
            (c + 1) as f64 * edge * r
        };
        let (first, end) = match self.exact {
            true => (lo.floor(), hi.ceil() - 1.0),
            false => ((lo - MARGIN).floor(), (hi + MARGIN).floor()),
        };
        let last = (self.counts - 1) as f64;
        (
            first.clamp(0.0, last) as usize,
            end.clamp(0.0, last) as usize,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Volume;

    fn levels(dims: [usize; 3]) -> BrickLevels {
        let v = Volume::new(
            dims,
            [1.0; 3],
            crate::VoxelData::U8(vec![0; dims.iter().product()]),
        )
        .unwrap();
        BrickLevels::of_volume(v).unwrap()
    }

    /// What the ray caster's lookup does in f32: the brick of level `level` at texture
    /// coordinate `t`.
    fn lookup(l: &BrickLevels, level: usize, t: [f32; 3]) -> [usize; 3] {
        let scale = l.texture_scale(level);
        let counts = l.levels()[level].counts;
        std::array::from_fn(|a| {
            let v = t[a].clamp(0.0, 1.0) * scale[a];
            ((v * (1.0 / BRICK as f32)).floor().max(0.0) as usize).min(counts[a] - 1)
        })
    }

    /// Texture coordinates along one axis: an even sweep, and the f32 values next to every
    /// brick boundary of level `level`.
    fn sweep(l: &BrickLevels, level: usize, axis: usize) -> Vec<f32> {
        let mut ts: Vec<f32> = (0..=4096).map(|i| i as f32 / 4096.0).collect();
        let scale = l.texture_scale(level)[axis];
        for b in 1..l.levels()[level].counts[axis] {
            let t = (b * BRICK) as f32 / scale;
            ts.extend([t.next_down(), t, t.next_up()]);
        }
        ts
    }

    /// Every sample the lookup places in a finer brick lands in the holder that `holder` names,
    /// on a pyramid whose levels halve exactly and on ones whose odd sizes round: a sweep of
    /// texture coordinates along each axis, with the points next to every brick boundary.
    #[test]
    fn a_holder_holds_every_sample_the_lookup_places_in_its_brick() {
        for dims in [[256, 128, 64], [200, 97, 75], [130, 66, 40]] {
            let l = levels(dims);
            let n = l.levels().len();
            let mut held = 0;
            for fine in 0..n {
                for coarse in fine + 1..n {
                    for a in 0..3 {
                        for t in sweep(&l, fine, a).into_iter().chain(sweep(&l, coarse, a)) {
                            let mut at = [0.5f32; 3];
                            at[a] = t;
                            let brick = lookup(&l, fine, at);
                            let key = BrickKey { level: fine, brick };
                            if let Some(h) = l.holder(key, coarse) {
                                held += 1;
                                assert_eq!(h, lookup(&l, coarse, at), "{dims:?} {key:?} {t}");
                            }
                        }
                    }
                }
            }
            assert!(held > 0, "{dims:?}");
        }
    }

    /// Scales that are not a power of two apart (a store's levels may be written so): a finer
    /// brick counts as held only where every f32 sample of it lands in that coarser brick.
    #[test]
    fn rounded_scales_hold_a_brick_only_where_every_sample_agrees() {
        let pairs: [(f32, f32); 4] = [
            (200.0, 200.0 / 2.1),
            (97.0, 48.5),
            (1000.0, 333.3),
            (64.0, 40.0),
        ];
        for (fine, coarse) in pairs {
            let counts = (fine as usize).div_ceil(BRICK);
            let coarse_counts = (coarse.ceil() as usize).div_ceil(BRICK);
            let axis = Axis::new(fine as f64, coarse as f64, [counts, coarse_counts]);
            let brick = |t: f32, scale: f32, n: usize| {
                ((t * scale * (1.0 / BRICK as f32)).floor().max(0.0) as usize).min(n - 1)
            };
            let (mut held, mut straddling) = (0, 0);
            for b in 0..counts {
                match axis.holder(b) {
                    Some(_) => held += 1,
                    None => straddling += 1,
                }
            }
            let mut t = 0.0f32;
            while t <= 1.0 {
                let b = brick(t, fine, counts);
                if let Some(h) = axis.holder(b) {
                    assert_eq!(h, brick(t, coarse, coarse_counts), "{fine} {coarse} {t}");
                }
                t = if t < 1.0 { (t + 1e-5).min(1.0) } else { 2.0 };
            }
            assert!(held > 0 && held + straddling == counts, "{fine} {coarse}");
        }
    }

    /// Where levels halve exactly, each brick of a level is held by its parent, and a coarse
    /// brick's finer bricks are exactly the ones under it.
    #[test]
    fn exact_halves_nest_as_a_tree() {
        let l = levels([256, 256, 256]);
        let key = BrickKey {
            level: 0,
            brick: [5, 2, 7],
        };
        assert_eq!(l.holder(key, 1), Some([2, 1, 3]));
        assert_eq!(l.holder(key, 2), Some([1, 0, 1]));
        let parent = BrickKey {
            level: 1,
            brick: [2, 1, 3],
        };
        let mut under = l.finer_overlapping(parent);
        under.sort_unstable();
        let mut want: Vec<usize> = (0..8)
            .map(|i| {
                let brick = [4 + (i & 1), 2 + (i >> 1 & 1), 6 + (i >> 2)];
                l.entry(BrickKey { level: 0, brick })
            })
            .collect();
        want.sort_unstable();
        assert_eq!(under, want);
    }

    /// Every finer brick a coarse brick holds is among the ones it overlaps.
    #[test]
    fn a_coarse_brick_overlaps_every_brick_it_holds() {
        let l = levels([200, 97, 75]);
        let n = l.levels().len();
        for coarse in 1..n {
            let c = &l.levels()[coarse];
            for e in c.first..c.first + c.bricks() {
                let key = l.key(e).unwrap();
                let over = l.finer_overlapping(key);
                for fine in 0..coarse {
                    let f = &l.levels()[fine];
                    for fe in f.first..f.first + f.bricks() {
                        let fk = l.key(fe).unwrap();
                        if l.holder(fk, coarse) == Some(key.brick) {
                            assert!(over.contains(&fe), "{fk:?} in {key:?}");
                        }
                    }
                }
            }
        }
    }

    /// Where two levels' scales are a power of two apart, a finer brick's holder is its index
    /// shifted by that power, as the voxels scaled into the coarser level say, for every pair of
    /// levels and every brick but the last along an axis (which takes the voxels up to the
    /// level's end).
    #[test]
    fn a_holder_of_levels_a_power_of_two_apart_is_the_shifted_index() {
        let mut shifted = 0;
        for dims in [[256, 128, 64], [200, 97, 75], [1000, 520, 130]] {
            let l = levels(dims);
            let n = l.levels().len();
            for fine in 0..n {
                for coarse in fine + 1..n {
                    for axis in l.axes(fine, coarse) {
                        if !axis.exact {
                            continue;
                        }
                        for b in 0..axis.counts - 1 {
                            assert_eq!(axis.holder(b), axis.holder_by_voxels(b), "{dims:?}");
                            shifted += 1;
                        }
                    }
                }
            }
        }
        assert!(shifted > 100, "{shifted}");
    }
}
