//! Voxel neighbourhoods as offset lists, and the grid arithmetic that visits them without leaving
//! the volume.
//!
//! Every neighbourhood in feature migration is one of the three cubic ones, named by how many
//! voxels they hold: 6 (faces), 18 (faces and edges) and 26 (the whole 3×3×3 block). A voxel's
//! neighbour outside the volume does not exist: it is neither ROI nor non-ROI. That is why an ROI
//! cut by the volume's edge has no boundary there (no material boundary was sampled).

use vellum_error::{Error, Result};

/// A cubic neighbourhood: which of the 26 surrounding voxels count as neighbours.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub enum Connectivity {
    /// The 6 face neighbours.
    Six,
    /// Faces and edges: the 3D grow of the paper's §3.2, its "3D version of the 8-neighbor
    /// (in 2D) region grow".
    Eighteen,
    /// The whole 3×3×3 block.
    TwentySix,
}

impl Connectivity {
    /// Parses `6`, `18` or `26`.
    pub fn parse(s: &str) -> Result<Self> {
        match s.trim() {
            "6" => Ok(Connectivity::Six),
            "18" => Ok(Connectivity::Eighteen),
            "26" => Ok(Connectivity::TwentySix),
            other => Err(Error::Invalid(format!(
                "connectivity '{other}' is invalid; expected 6, 18 or 26"
            ))),
        }
    }

    /// The number of neighbours (6, 18 or 26).
    pub fn count(self) -> usize {
        match self {
            Connectivity::Six => 6,
            Connectivity::Eighteen => 18,
            Connectivity::TwentySix => 26,
        }
    }

    /// The neighbour offsets: every d in {-1, 0, 1}³ \ {0} with at most 1, 2 or 3 non-zero
    /// components.
    pub(crate) fn offsets(self) -> Vec<[i32; 3]> {
        let max_nonzero = match self {
            Connectivity::Six => 1,
            Connectivity::Eighteen => 2,
            Connectivity::TwentySix => 3,
        };
        cube(1)
            .filter(|d| {
                let nonzero = d.iter().filter(|&&c| c != 0).count();
                (1..=max_nonzero).contains(&nonzero)
            })
            .collect()
    }
}

/// Every offset in [-r, r]³, z slowest.
fn cube(r: i32) -> impl Iterator<Item = [i32; 3]> {
    (-r..=r).flat_map(move |z| (-r..=r).flat_map(move |y| (-r..=r).map(move |x| [x, y, z])))
}

/// How many steps of the 18-neighbourhood it takes to reach offset `d` from the origin:
/// max(‖d‖∞, ⌈‖d‖₁ / 2⌉). A step changes at most two coordinates by one each, so neither norm can
/// fall faster than that, and moving the two largest coordinates towards zero achieves it.
pub(crate) fn steps_18(d: [i32; 3]) -> u32 {
    let a = d.map(|c| c.unsigned_abs());
    let inf = a[0].max(a[1]).max(a[2]);
    let l1 = a[0] + a[1] + a[2];
    inf.max(l1.div_ceil(2))
}

/// The rings of an iterated 18-neighbour region grow around a voxel: `rings(n)[k - 1]` holds the
/// offsets first reached in iteration k (k = 1..=n). Ring 1 is the 18-neighbourhood itself.
pub(crate) fn rings_18(iterations: u32) -> Vec<Vec<[i32; 3]>> {
    let r = iterations as i32;
    let mut rings = vec![Vec::new(); iterations as usize];
    for d in cube(r) {
        let k = steps_18(d);
        if (1..=iterations).contains(&k) {
            rings[k as usize - 1].push(d);
        }
    }
    rings
}

/// Index arithmetic on an x-fastest grid.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Grid {
    /// Voxels along x, y, z.
    pub dims: [usize; 3],
}

impl Grid {
    /// The grid of a volume with `dims`.
    pub fn new(dims: [usize; 3]) -> Self {
        Grid { dims }
    }

    /// Number of voxels.
    pub fn len(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }

    /// True for a grid without voxels.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Linear index of voxel (x, y, z).
    #[inline]
    pub fn index(&self, p: [usize; 3]) -> usize {
        p[0] + self.dims[0] * (p[1] + self.dims[1] * p[2])
    }

    /// Coordinates of linear index `i`.
    #[inline]
    pub fn coords(&self, i: usize) -> [usize; 3] {
        let x = i % self.dims[0];
        let yz = i / self.dims[0];
        [x, yz % self.dims[1], yz / self.dims[1]]
    }

    /// The linear index of `p + d`, or `None` when that lies outside the grid.
    #[inline]
    pub fn offset(&self, p: [usize; 3], d: [i32; 3]) -> Option<usize> {
        let mut q = [0usize; 3];
        for a in 0..3 {
            let c = p[a] as i64 + d[a] as i64;
            if c < 0 || c >= self.dims[a] as i64 {
                return None;
            }
            q[a] = c as usize;
        }
        Some(self.index(q))
    }

    /// `offsets` prepared for visiting on this grid.
    pub fn stencil(&self, offsets: Vec<[i32; 3]>) -> Stencil {
        let linear = offsets
            .iter()
            .map(|d| {
                d[0] as isize
                    + self.dims[0] as isize
                        * (d[1] as isize + self.dims[1] as isize * d[2] as isize)
            })
            .collect();
        let reach = offsets
            .iter()
            .flatten()
            .map(|c| c.unsigned_abs() as usize)
            .max()
            .unwrap_or(0);
        Stencil {
            offsets,
            linear,
            reach,
        }
    }

    /// True when every offset of `s` from `p` stays inside the grid.
    #[inline]
    fn holds(&self, p: [usize; 3], s: &Stencil) -> bool {
        (0..3).all(|a| p[a] >= s.reach && p[a] + s.reach < self.dims[a])
    }

    /// Calls `f` with the linear index of every neighbour of `p` (linear index `i`) in `s` that
    /// lies inside the grid, stopping at the first `true`; returns whether one did.
    #[inline]
    pub fn any(
        &self,
        p: [usize; 3],
        i: usize,
        s: &Stencil,
        mut f: impl FnMut(usize) -> bool,
    ) -> bool {
        if self.holds(p, s) {
            s.linear.iter().any(|&o| f(i.wrapping_add_signed(o)))
        } else {
            s.offsets
                .iter()
                .any(|&d| self.offset(p, d).is_some_and(&mut f))
        }
    }

    /// Calls `f` with the linear index of every neighbour of `p` (linear index `i`) in `s` that
    /// lies inside the grid.
    #[inline]
    pub(crate) fn visit(&self, p: [usize; 3], i: usize, s: &Stencil, mut f: impl FnMut(usize)) {
        self.any(p, i, s, |q| {
            f(q);
            false
        });
    }
}

/// Neighbour offsets together with their linear-index steps on one grid. Where the whole stencil
/// lies inside the grid (almost everywhere) neighbours are visited by adding the steps, with no
/// bounds checks; near the faces each offset is checked.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Stencil {
    /// The offsets.
    pub(crate) offsets: Vec<[i32; 3]>,
    /// The same offsets as steps of the linear index.
    pub linear: Vec<isize>,
    /// The largest |component| of any offset.
    pub reach: usize,
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::VecDeque;

    #[test]
    fn neighbourhood_sizes_and_shapes() {
        for c in [
            Connectivity::Six,
            Connectivity::Eighteen,
            Connectivity::TwentySix,
        ] {
            let o = c.offsets();
            assert_eq!(o.len(), c.count());
            assert!(!o.contains(&[0, 0, 0]));
        }
        let six = Connectivity::Six.offsets();
        assert!(six.contains(&[0, 0, -1]) && !six.contains(&[1, 1, 0]));
        let eighteen = Connectivity::Eighteen.offsets();
        assert!(eighteen.contains(&[1, -1, 0]) && !eighteen.contains(&[1, 1, 1]));
        assert!(Connectivity::TwentySix.offsets().contains(&[-1, 1, 1]));
        assert_eq!(Connectivity::parse("26").unwrap(), Connectivity::TwentySix);
        let e = Connectivity::parse("8").unwrap_err().to_string();
        assert!(e.contains("expected 6, 18 or 26"), "{e}");
    }

    /// `steps_18` agrees with a breadth-first search over the 18-neighbourhood.
    #[test]
    fn steps_18_matches_bfs() {
        let r = 4i32;
        let side = (2 * r + 1) as usize;
        let grid = Grid::new([side; 3]);
        let centre = [r as usize; 3];
        let mut dist = vec![u32::MAX; grid.len()];
        dist[grid.index(centre)] = 0;
        let mut queue = VecDeque::from([centre]);
        let offs = Connectivity::Eighteen.offsets();
        while let Some(p) = queue.pop_front() {
            let dp = dist[grid.index(p)];
            for &d in &offs {
                if let Some(q) = grid.offset(p, d) {
                    if dist[q] == u32::MAX {
                        dist[q] = dp + 1;
                        queue.push_back(grid.coords(q));
                    }
                }
            }
        }
        for d in cube(r) {
            let p = [
                (d[0] + r) as usize,
                (d[1] + r) as usize,
                (d[2] + r) as usize,
            ];
            assert_eq!(steps_18(d), dist[grid.index(p)], "{d:?}");
        }
    }

    #[test]
    fn rings_partition_the_three_step_ball() {
        let rings = rings_18(3);
        assert_eq!(rings[0].len(), 18);
        let mut sorted = rings[0].clone();
        sorted.sort();
        let mut eighteen = Connectivity::Eighteen.offsets();
        eighteen.sort();
        assert_eq!(sorted, eighteen);
        // |{d : steps ≤ 2}| − 1 and |{d : steps ≤ 3}| − 1, counted independently below.
        let within = |k: u32| cube(3).filter(|&d| steps_18(d) <= k).count() - 1;
        assert_eq!(rings[1].len(), within(2) - 18);
        assert_eq!(rings[2].len(), within(3) - within(2));
        assert!(rings[1].contains(&[1, 1, 1]) && rings[2].contains(&[3, 0, 0]));
        assert!(!rings.iter().flatten().any(|&d| d == [3, 3, 1]));
    }

    #[test]
    fn grid_offsets_stay_inside() {
        let g = Grid::new([4, 3, 2]);
        assert_eq!(g.len(), 24);
        for i in 0..g.len() {
            assert_eq!(g.index(g.coords(i)), i);
        }
        assert_eq!(g.offset([0, 0, 0], [-1, 0, 0]), None);
        assert_eq!(g.offset([3, 2, 1], [0, 0, 1]), None);
        assert_eq!(g.offset([1, 1, 0], [1, 1, 1]), Some(g.index([2, 2, 1])));
    }

    /// The unchecked path (inside) and the checked path (near faces) visit the same voxels.
    #[test]
    fn stencil_visits_the_in_grid_neighbours() {
        let g = Grid::new([7, 6, 5]);
        let s = g.stencil(Connectivity::Eighteen.offsets());
        assert_eq!(s.reach, 1);
        for i in 0..g.len() {
            let p = g.coords(i);
            let mut seen = Vec::new();
            g.visit(p, i, &s, |q| seen.push(q));
            let want: Vec<usize> = s.offsets.iter().filter_map(|&d| g.offset(p, d)).collect();
            assert_eq!(seen, want, "{p:?}");
        }
        let centre = g.index([3, 3, 2]);
        assert!(g.any([3, 3, 2], centre, &s, |q| q == g.index([4, 4, 2])));
        assert!(!g.any([3, 3, 2], centre, &s, |q| q == g.index([4, 4, 3])));
    }
}
