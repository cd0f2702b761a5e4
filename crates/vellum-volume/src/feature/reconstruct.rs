//! FM4, fuzzy boundary reconstruction (paper §3.4): every category-1 voxel p gets a new value from
//! the mean intensities of the nearest ROI and non-ROI voxels around it (eqs. 6, 7) through the
//! intensity-flipping map of eq. 10, so the boundary keeps its place while the ROI side moves by Δ.
//!
//! Step 1, the region grow around p, is read as follows. Iteration k adds the voxels k steps of
//! the 18-neighbourhood away from p (the paper's grow of §3.2, repeated), so iteration 1 is the 18
//! neighbours and iteration 3 reaches "a 3-voxel radius". Category-1 voxels are passed over but
//! never counted ("ignored"; p is surrounded by them, so the grow cannot stop at them). The grow
//! stops after the first iteration that holds ≥ l ROI voxels (categories 2 or 3) or ≥ g category-2
//! voxels, and ≥ l category-4 voxels, and after 3 iterations in any case. Whole iterations are
//! counted, so the sums of eqs. 6 and 7 run over every voxel of the last iteration, equally near.
//! All intensities are the original ones ("in the original dataset").
//!
//! Step 2 and the degenerate cases, as §3.4 states them:
//! - both sides found, δ_p between δ_o and δ_i: eq. 10;
//! - δ_p beyond δ_i (on the far side of δ_i from δ_o): shifted as a category-2/3 voxel (eq. 5);
//!   beyond δ_o: left unchanged as a category-4 voxel;
//! - only ROI voxels found (λ_i > 0, λ_o = 0): shifted (eq. 5); only outside voxels: unchanged;
//! - fewer than l (or g) voxels on a side but more than none: eqs. 6 and 7 over what was found.
//!
//! Two cases the paper does not name are decided by the ROI mask (shift if p is in the ROI, else
//! keep): no voxel of either side within 3 iterations, and δ_i = δ_o, where eq. 10 divides by zero
//! and the intensities cannot say which side p is on.
//!
//! "Beyond" is measured along the direction from δ_o to δ_i, so an ROI darker than its
//! surroundings (bone in T1 MRI) is handled like a brighter one.

use rayon::prelude::*;
use serde::Serialize;

use super::categorise::{Categories, Category};
use super::neighbourhood::{rings_18, Grid, Stencil};
use super::roi::Roi;

/// The parameters of step 1's region grow (paper §3.4: l = 5, g = 3, at most 3 iterations).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct RegionGrow {
    /// l: ROI voxels (categories 2 or 3) and outside voxels (category 4) to find.
    pub l: usize,
    /// g: category-2 voxels that suffice on the ROI side (a thin ROI).
    pub g: usize,
    /// Iterations after which the grow stops regardless.
    pub(crate) max_iterations: u32,
}

impl Default for RegionGrow {
    fn default() -> Self {
        RegionGrow {
            l: 5,
            g: 3,
            max_iterations: 3,
        }
    }
}

/// What the region grow around one voxel found.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct LocalMeans {
    /// λ_i: ROI voxels (categories 2 and 3) found.
    pub(crate) lambda_i: usize,
    /// γ_i: category-2 voxels found (a subset of λ_i).
    pub(crate) gamma_i: usize,
    /// λ_o: category-4 voxels found.
    pub(crate) lambda_o: usize,
    /// δ_i (eq. 6): the mean of the category-2 voxels when γ_i ≥ g, else of all λ_i ROI voxels;
    /// `None` when λ_i = 0.
    pub(crate) delta_i: Option<f64>,
    /// δ_o (eq. 7): the mean of the λ_o outside voxels; `None` when λ_o = 0.
    pub(crate) delta_o: Option<f64>,
    /// Iterations run.
    pub(crate) iterations: u32,
}

/// How a category-1 voxel got its new value.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize)]
pub(crate) enum Case {
    /// Eq. 10.
    Flipped,
    /// Only ROI voxels were found: shifted by Δ (eq. 5).
    InsideOnly,
    /// Only outside voxels were found: unchanged.
    OutsideOnly,
    /// δ_p lies beyond δ_i: shifted by Δ.
    BeyondInside,
    /// δ_p lies beyond δ_o: unchanged.
    BeyondOutside,
    /// Neither side found, or δ_i = δ_o: shifted if p is in the ROI mask, else unchanged.
    ByMask,
}

/// Number of category-1 voxels per `Case`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct ReconstructionCounts {
    /// Eq. 10.
    pub flipped: usize,
    /// Only ROI voxels found, shifted.
    pub inside_only: usize,
    /// Only outside voxels found, unchanged.
    pub outside_only: usize,
    /// Beyond δ_i, shifted.
    pub beyond_inside: usize,
    /// Beyond δ_o, unchanged.
    pub beyond_outside: usize,
    /// Decided by the mask.
    pub by_mask: usize,
}

impl ReconstructionCounts {
    fn add(&mut self, case: Case) {
        *match case {
            Case::Flipped => &mut self.flipped,
            Case::InsideOnly => &mut self.inside_only,
            Case::OutsideOnly => &mut self.outside_only,
            Case::BeyondInside => &mut self.beyond_inside,
            Case::BeyondOutside => &mut self.beyond_outside,
            Case::ByMask => &mut self.by_mask,
        } += 1;
    }

    fn merge(mut self, o: Self) -> Self {
        self.flipped += o.flipped;
        self.inside_only += o.inside_only;
        self.outside_only += o.outside_only;
        self.beyond_inside += o.beyond_inside;
        self.beyond_outside += o.beyond_outside;
        self.by_mask += o.by_mask;
        self
    }

    /// All category-1 voxels handled.
    pub fn total(&self) -> usize {
        self.flipped
            + self.inside_only
            + self.outside_only
            + self.beyond_inside
            + self.beyond_outside
            + self.by_mask
    }
}

/// Eq. 10: δ′_p = δ_o + (δ_p − δ_o)/(δ_i − δ_o) · (δ_i + Δ − δ_o). Requires δ_i ≠ δ_o.
#[inline]
pub(crate) fn eq10(delta_p: f64, delta_i: f64, delta_o: f64, delta: f64) -> f64 {
    delta_o + (delta_p - delta_o) / (delta_i - delta_o) * (delta_i + delta - delta_o)
}

/// Step 2 for one voxel: its new value and the case that produced it. `in_roi` is the mask bit of
/// p, used only where intensities cannot decide (see the module doc).
pub(crate) fn new_value(delta_p: f64, means: &LocalMeans, delta: f64, in_roi: bool) -> (f64, Case) {
    let by_mask = if in_roi { delta_p + delta } else { delta_p };
    match (means.delta_i, means.delta_o) {
        (None, None) => (by_mask, Case::ByMask),
        (Some(_), None) => (delta_p + delta, Case::InsideOnly),
        (None, Some(_)) => (delta_p, Case::OutsideOnly),
        (Some(di), Some(d_o)) if di == d_o => (by_mask, Case::ByMask),
        (Some(di), Some(d_o)) => {
            // Position of δ_p on the way from δ_o (0) to δ_i (1).
            let t = (delta_p - d_o) / (di - d_o);
            if t > 1.0 {
                (delta_p + delta, Case::BeyondInside)
            } else if t < 0.0 {
                (delta_p, Case::BeyondOutside)
            } else {
                (eq10(delta_p, di, d_o, delta), Case::Flipped)
            }
        }
    }
}

/// The rings of step 1's region grow as stencils on `grid` (see [`rings_18`]).
pub(crate) fn grow_rings(grid: Grid, grow: &RegionGrow) -> Vec<Stencil> {
    rings_18(grow.max_iterations)
        .into_iter()
        .map(|ring| grid.stencil(ring))
        .collect()
}

/// Step 1 for the voxel at `p`: the region grow over the `rings` (from [`grow_rings`]) and the
/// means of eqs. 6 and 7 over the original `values`.
pub(crate) fn local_means(
    grid: Grid,
    labels: &[Category],
    values: &[f32],
    p: [usize; 3],
    rings: &[Stencil],
    grow: &RegionGrow,
) -> LocalMeans {
    let i = grid.index(p);
    let (mut lambda_i, mut gamma_i, mut lambda_o) = (0usize, 0usize, 0usize);
    let (mut sum_i, mut sum_2, mut sum_o) = (0.0f64, 0.0f64, 0.0f64);
    let mut iterations = 0;
    for ring in rings.iter().take(grow.max_iterations as usize) {
        iterations += 1;
        grid.visit(p, i, ring, |q| match labels[q] {
            Category::FuzzyBoundary => {}
            Category::ThinRoi => {
                let v = values[q] as f64;
                lambda_i += 1;
                gamma_i += 1;
                sum_i += v;
                sum_2 += v;
            }
            Category::RoiInterior => {
                lambda_i += 1;
                sum_i += values[q] as f64;
            }
            Category::Outside => {
                lambda_o += 1;
                sum_o += values[q] as f64;
            }
        });
        if (lambda_i >= grow.l || gamma_i >= grow.g) && lambda_o >= grow.l {
            break;
        }
    }
    // Eq. 6: the thin-ROI mean when g category-2 voxels were found.
    let delta_i = if gamma_i >= grow.g && gamma_i > 0 {
        Some(sum_2 / gamma_i as f64)
    } else if lambda_i > 0 {
        Some(sum_i / lambda_i as f64)
    } else {
        None
    };
    let delta_o = (lambda_o > 0).then(|| sum_o / lambda_o as f64);
    LocalMeans {
        lambda_i,
        gamma_i,
        lambda_o,
        delta_i,
        delta_o,
        iterations,
    }
}

/// Writes the reconstructed value of every category-1 voxel into `out` (other voxels are left as
/// they are) and counts the cases. `values` are the original intensities, `delta` is Δ (eq. 4).
pub(crate) fn reconstruct(
    categories: &Categories,
    roi: &Roi,
    values: &[f32],
    delta: f64,
    grow: &RegionGrow,
    out: &mut [f64],
) -> ReconstructionCounts {
    let grid = Grid::new(categories.dims);
    let [nx, ny, _] = grid.dims;
    let rings = grow_rings(grid, grow);
    let labels = &categories.labels;
    out.par_chunks_mut(nx)
        .enumerate()
        .map(|(row, out_row)| {
            let (y, z) = (row % ny, row / ny);
            let mut counts = ReconstructionCounts::default();
            for (x, o) in out_row.iter_mut().enumerate() {
                let i = row * nx + x;
                if labels[i] != Category::FuzzyBoundary {
                    continue;
                }
                let means = local_means(grid, labels, values, [x, y, z], &rings, grow);
                let (v, case) = new_value(values[i] as f64, &means, delta, roi.contains(i));
                *o = v;
                counts.add(case);
            }
            counts
        })
        .reduce(ReconstructionCounts::default, ReconstructionCounts::merge)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::feature::categorise::categorise;

    fn means(delta_i: Option<f64>, delta_o: Option<f64>) -> LocalMeans {
        LocalMeans {
            delta_i,
            delta_o,
            ..Default::default()
        }
    }

    #[test]
    fn eq10_maps_the_outside_mean_to_itself_and_the_inside_mean_by_delta() {
        let (di, d_o, delta) = (200.0, 50.0, 100.0);
        assert_eq!(eq10(d_o, di, d_o, delta), d_o);
        assert_eq!(eq10(di, di, d_o, delta), di + delta);
        // Halfway stays halfway: 125 → 50 + 0.5 · 250.
        assert_eq!(eq10(125.0, di, d_o, delta), 175.0);
        // A dark ROI (δ_i < δ_o) flips the profile's direction but keeps the proportions.
        assert_eq!(
            eq10(125.0, 50.0, 200.0, 300.0),
            200.0 + 0.5 * (350.0 - 200.0)
        );
    }

    #[test]
    fn degenerate_cases_follow_the_paper() {
        let d = 100.0;
        let both = means(Some(200.0), Some(50.0));
        assert_eq!(new_value(125.0, &both, d, false), (175.0, Case::Flipped));
        assert_eq!(
            new_value(220.0, &both, d, false),
            (320.0, Case::BeyondInside)
        );
        assert_eq!(new_value(40.0, &both, d, true), (40.0, Case::BeyondOutside));
        // Dark ROI: "beyond δ_i" is below it.
        let dark = means(Some(30.0), Some(150.0));
        assert_eq!(
            new_value(20.0, &dark, d, false),
            (120.0, Case::BeyondInside)
        );
        assert_eq!(
            new_value(160.0, &dark, d, true),
            (160.0, Case::BeyondOutside)
        );
        let inside = means(Some(200.0), None);
        assert_eq!(
            new_value(90.0, &inside, d, false),
            (190.0, Case::InsideOnly)
        );
        let outside = means(None, Some(50.0));
        assert_eq!(
            new_value(190.0, &outside, d, true),
            (190.0, Case::OutsideOnly)
        );
        let none = means(None, None);
        assert_eq!(new_value(90.0, &none, d, true), (190.0, Case::ByMask));
        assert_eq!(new_value(90.0, &none, d, false), (90.0, Case::ByMask));
        let equal = means(Some(70.0), Some(70.0));
        assert_eq!(new_value(70.0, &equal, d, true), (170.0, Case::ByMask));
        assert_eq!(new_value(70.0, &equal, d, false), (70.0, Case::ByMask));
    }

    /// A slab x >= 5 in a 12×7×7 grid: the inner shell voxel (x = 6) finds its 5 ROI voxels in
    /// iteration 1 (x = 7: 1 face + 4 edge neighbours) but the outside only in iteration 3 (x = 3).
    #[test]
    fn region_grow_stops_when_both_sides_are_found() {
        let dims = [12, 7, 7];
        let grid = Grid::new(dims);
        let roi = Roi::new(
            dims,
            (0..grid.len()).map(|i| grid.coords(i)[0] >= 5).collect(),
        )
        .unwrap();
        let cats = categorise(&roi);
        let values: Vec<f32> = (0..grid.len())
            .map(|i| if roi.contains(i) { 200.0 } else { 50.0 })
            .collect();
        let grow = RegionGrow::default();
        let rings = grow_rings(grid, &grow);
        let m = local_means(grid, &cats.labels, &values, [6, 3, 3], &rings, &grow);
        assert_eq!(m.iterations, 3);
        assert_eq!(m.delta_i, Some(200.0));
        assert_eq!(m.delta_o, Some(50.0));
        assert_eq!(m.gamma_i, 0);
        // Iteration 3 adds x = 3 (offset −3: only the straight one plus its ring with ‖d‖₁ ≤ 6).
        assert!(m.lambda_o >= 5, "{m:?}");
        // The boundary voxel x = 5 finds both sides in iteration 2 (x = 3 and x = 7).
        let m = local_means(grid, &cats.labels, &values, [5, 3, 3], &rings, &grow);
        assert_eq!(m.iterations, 2);
        // One iteration is not enough for anyone in the band, so the limit leaves sides empty.
        let one = RegionGrow {
            max_iterations: 1,
            ..grow
        };
        let m = local_means(grid, &cats.labels, &values, [5, 3, 3], &rings, &one);
        assert_eq!((m.delta_i, m.delta_o), (None, None));
    }

    #[test]
    fn thin_roi_uses_the_category_2_mean() {
        // A two-voxel-thick sheet (all type 2) at x = 5, 6 with values 180 and 220 in a
        // background of 50: the shell voxel x = 4 finds 5 category-2 voxels in iteration 1.
        let dims = [12, 9, 9];
        let grid = Grid::new(dims);
        let roi = Roi::new(
            dims,
            (0..grid.len())
                .map(|i| matches!(grid.coords(i)[0], 5 | 6))
                .collect(),
        )
        .unwrap();
        let cats = categorise(&roi);
        assert_eq!(cats.labels[grid.index([5, 4, 4])], Category::ThinRoi);
        let values: Vec<f32> = (0..grid.len())
            .map(|i| match grid.coords(i)[0] {
                5 => 180.0,
                6 => 220.0,
                _ => 50.0,
            })
            .collect();
        let m = local_means(
            grid,
            &cats.labels,
            &values,
            [4, 4, 4],
            &grow_rings(grid, &RegionGrow::default()),
            &RegionGrow::default(),
        );
        assert_eq!((m.iterations, m.gamma_i, m.lambda_o), (1, 5, 5), "{m:?}");
        assert_eq!(m.delta_i, Some(180.0));
        assert_eq!(m.delta_o, Some(50.0));
    }
}
