//! The processes that share one job (issue 27): a process alone ([`Solo`]), or the ranks of an
//! MPI job (`cluster::MpiTeam`, behind the `mpi` feature). Work that runs chunk by chunk asks its
//! team which chunks are its own (`kd_owners`), agrees with the others after each step (one
//! failed rank ends every rank with its sentence), and reduces what is global (a value range,
//! the spectrum's counts). Nothing here knows MPI, and nothing beneath `cluster` imports it.

use vellum_error::{Error, Result};

/// The ranks of a job, as the passes see them. Every method but `rank` and `size` is collective:
/// every rank calls it, in the same order.
pub trait Team {
    /// This rank's number, from 0.
    fn rank(&self) -> usize;
    /// Ranks in the job.
    fn size(&self) -> usize;
    /// Every rank's outcome of a step: `Ok` when all succeeded, else the sentence of the lowest
    /// failed rank, as `rank R: …` when the team has more than one.
    fn agree(&self, outcome: Result<()>) -> Result<()>;
    /// The smallest of the `[0]`s and the largest of the `[1]`s over the ranks.
    fn min_max(&self, range: [f64; 2]) -> [f64; 2];
    /// `counts` summed element by element over the ranks (every rank passes the same length).
    fn sum(&self, counts: &mut [u64]);
    /// Rank 0's `bytes`, on every rank.
    fn broadcast(&self, bytes: Vec<u8>) -> Vec<u8>;
    /// Returns once every rank has called it: the end of a job, after rank 0 has said how it
    /// went (a launcher ends the whole job when any rank exits with an error, which could cut
    /// rank 0 off before its sentence).
    fn barrier(&self);
    /// All to all: `send.0` holds `send.1[r]` values for each rank r in rank order, and
    /// `recv.0` receives `recv.1[r]` values from each rank r, in rank order.
    fn exchange(&self, send: (&[f32], &[usize]), recv: (&mut [f32], &[usize]));
    /// Sends `send` to `partner` and receives `recv` from it, at once.
    fn swap(&self, partner: usize, send: &[f32], recv: &mut [f32]);
    /// Every rank's `send` (`counts[r]` values from rank r) into rank 0's `recv`, in rank order
    /// (`recv` is not touched elsewhere).
    fn gather(&self, send: &[f32], counts: &[usize], recv: &mut [f32]);
}

impl dyn Team + '_ {
    /// Refuses the job, on every rank, when its ranks were given different inputs: `key` (a
    /// digest of the command line and what it opened) differs between ranks.
    pub fn same_inputs(&self, key: u64) -> Result<()> {
        let root = u64::from_le_bytes(
            self.broadcast(key.to_le_bytes().to_vec())
                .try_into()
                .map_err(|_| Error::Invalid("rank 0's input key did not arrive whole".into()))?,
        );
        let outcome = match root == key {
            true => Ok(()),
            false => Err(Error::Invalid(
                "its command line or inputs differ from rank 0's; every rank of a job must be given the same command and the same input".into(),
            )),
        };
        self.agree(outcome)
    }

    /// Whether this rank writes what one rank writes for all (metadata, the image).
    pub fn is_root(&self) -> bool {
        self.rank() == 0
    }

    /// `r` when every rank's step succeeded, else the agreed sentence ([`Team::agree`]) on every
    /// rank: what a rank does before the others may go on (open its input, make its pipeline).
    pub fn together<T>(&self, r: Result<T>) -> Result<T> {
        if self.size() == 1 {
            return r;
        }
        let outcome = r
            .as_ref()
            .map(|_| ())
            .map_err(|e| Error::Invalid(e.to_string()));
        self.agree(outcome)?;
        r
    }
}

/// A process alone: rank 0 of 1.
pub struct Solo;

impl Team for Solo {
    fn rank(&self) -> usize {
        0
    }
    fn size(&self) -> usize {
        1
    }
    fn agree(&self, outcome: Result<()>) -> Result<()> {
        outcome
    }
    fn min_max(&self, range: [f64; 2]) -> [f64; 2] {
        range
    }
    fn sum(&self, _counts: &mut [u64]) {}
    fn broadcast(&self, bytes: Vec<u8>) -> Vec<u8> {
        bytes
    }
    fn barrier(&self) {}
    fn exchange(&self, send: (&[f32], &[usize]), recv: (&mut [f32], &[usize])) {
        recv.0.copy_from_slice(send.0);
    }
    fn swap(&self, _partner: usize, send: &[f32], recv: &mut [f32]) {
        recv.copy_from_slice(send);
    }
    fn gather(&self, send: &[f32], _counts: &[usize], recv: &mut [f32]) {
        recv.copy_from_slice(send);
    }
}

/// How many ranks the launcher that started this process says the job has, when one did
/// (Open MPI's `mpirun`, MPICH's Hydra, PMIx, Slurm's `srun`); `Some(0)` when it did not say.
/// `None`: run alone, as every command does without a launcher.
pub fn launched_ranks() -> Option<usize> {
    let var = |k: &str| std::env::var(k).ok();
    let size = ["OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "SLURM_STEP_NUM_TASKS"]
        .iter()
        .find_map(|k| var(k)?.trim().parse::<usize>().ok());
    match size {
        Some(n) => Some(n),
        None => var("PMIX_RANK").map(|_| 0),
    }
}

/// A box of cells of a grid: `lo .. hi` along x, y, z.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CellBox {
    /// The first cell along x, y, z.
    pub lo: [usize; 3],
    /// One past the last cell along x, y, z.
    pub hi: [usize; 3],
}

impl CellBox {
    /// Whether cell `c` lies in the box.
    pub fn contains(&self, c: [usize; 3]) -> bool {
        (0..3).all(|a| self.lo[a] <= c[a] && c[a] < self.hi[a])
    }
}

/// Splits a grid of `counts` cells (x fastest) into `parts` boxes, one per rank, by a k-d split:
/// each box is cut across its longest axis where the weights on either side are closest to the
/// ratio of the ranks each side gets. A weight is what a cell costs (1 for each when `weights`
/// is empty). A box may be empty when there are more ranks than cells.
pub(crate) fn kd_split(counts: [usize; 3], weights: &[f64], parts: usize) -> Vec<CellBox> {
    KdTree::new(counts, weights, parts).boxes
}

/// A k-d split of a grid among ranks: their boxes (rank order), and the cuts that made them,
/// which give the boxes' order along any ray from an eye.
pub struct KdTree {
    /// The ranks' boxes, in rank order.
    pub boxes: Vec<CellBox>,
    root: Node,
}

enum Node {
    /// A rank's box.
    Leaf(usize),
    /// Cells below `cut` along `axis` go left, the rest right.
    Cut {
        axis: usize,
        cut: usize,
        left: Box<Node>,
        right: Box<Node>,
    },
}

impl KdTree {
    /// See `kd_split`.
    pub fn new(counts: [usize; 3], weights: &[f64], parts: usize) -> Self {
        let whole = CellBox {
            lo: [0; 3],
            hi: counts,
        };
        let mut boxes = Vec::with_capacity(parts);
        let root = split_into(whole, counts, weights, parts.max(1), &mut boxes);
        KdTree { boxes, root }
    }

    /// The ranks front to back as seen from `eye` (in cells; far outside the grid against the
    /// view direction for a parallel projection): at each cut, the side the eye is on first. The
    /// boxes are convex and the cuts are planes, so this is the order along every ray.
    pub fn order(&self, eye: [f64; 3]) -> Vec<usize> {
        let mut out = Vec::with_capacity(self.boxes.len());
        fn walk(n: &Node, eye: [f64; 3], out: &mut Vec<usize>) {
            match n {
                Node::Leaf(r) => out.push(*r),
                Node::Cut {
                    axis,
                    cut,
                    left,
                    right,
                } => {
                    let (first, second) = match eye[*axis] < *cut as f64 {
                        true => (left, right),
                        false => (right, left),
                    };
                    walk(first, eye, out);
                    walk(second, eye, out);
                }
            }
        }
        walk(&self.root, eye, &mut out);
        out
    }
}

fn split_into(
    b: CellBox,
    counts: [usize; 3],
    weights: &[f64],
    parts: usize,
    out: &mut Vec<CellBox>,
) -> Node {
    let extent: [usize; 3] = std::array::from_fn(|a| b.hi[a] - b.lo[a]);
    let axis = (0..3).max_by_key(|&a| (extent[a], a)).unwrap_or(0);
    if parts == 1 || extent[axis] < 2 {
        // Ranks beyond what the box can be cut into get empty boxes (at its far corner).
        let first = out.len();
        out.push(b);
        for _ in 1..parts {
            out.push(CellBox { lo: b.hi, hi: b.hi });
        }
        let mut node = Node::Leaf(first + parts - 1);
        for r in (first..first + parts - 1).rev() {
            node = Node::Cut {
                axis,
                cut: b.hi[axis],
                left: Box::new(Node::Leaf(r)),
                right: Box::new(node),
            };
        }
        return node;
    }
    // The weight of each slab across `axis`.
    let mut slabs = vec![0f64; extent[axis]];
    for z in b.lo[2]..b.hi[2] {
        for y in b.lo[1]..b.hi[1] {
            for x in b.lo[0]..b.hi[0] {
                let c = [x, y, z];
                let w = weights
                    .get(x + counts[0] * (y + counts[1] * z))
                    .copied()
                    .unwrap_or(1.0);
                slabs[c[axis] - b.lo[axis]] += w;
            }
        }
    }
    let left_parts = parts / 2;
    let total: f64 = slabs.iter().sum();
    let goal = total * left_parts as f64 / parts as f64;
    // The cut after slab k (1 ..= extent - 1) whose left weight is nearest the goal.
    let mut acc = 0.0;
    let mut best = (f64::INFINITY, 1);
    for (k, w) in slabs.iter().enumerate().take(extent[axis] - 1) {
        acc += w;
        let d = (acc - goal).abs();
        if d < best.0 {
            best = (d, k + 1);
        }
    }
    let cut = b.lo[axis] + best.1;
    let (mut left, mut right) = (b, b);
    left.hi[axis] = cut;
    right.lo[axis] = cut;
    let left = Box::new(split_into(left, counts, weights, left_parts, out));
    let right = Box::new(split_into(right, counts, weights, parts - left_parts, out));
    Node::Cut {
        axis,
        cut,
        left,
        right,
    }
}

/// The owner of each cell of a grid of `counts` (x fastest) under the boxes of [`kd_split`].
pub(crate) fn kd_owners(counts: [usize; 3], weights: &[f64], parts: usize) -> Vec<usize> {
    let boxes = kd_split(counts, weights, parts);
    let mut owner = vec![0; counts[0] * counts[1] * counts[2]];
    for (rank, b) in boxes.iter().enumerate() {
        for z in b.lo[2]..b.hi[2] {
            for y in b.lo[1]..b.hi[1] {
                for x in b.lo[0]..b.hi[0] {
                    owner[x + counts[0] * (y + counts[1] * z)] = rank;
                }
            }
        }
    }
    owner
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_kd_split_covers_the_grid_once_and_balances_its_weights() {
        let counts = [8, 4, 4];
        for parts in 1..=9 {
            let boxes = kd_split(counts, &[], parts);
            assert_eq!(boxes.len(), parts);
            let owners = kd_owners(counts, &[], parts);
            let mut per = vec![0; parts];
            for &o in &owners {
                per[o] += 1;
            }
            // Every cell is in exactly one box.
            for z in 0..4 {
                for y in 0..4 {
                    for x in 0..8 {
                        let n = boxes.iter().filter(|b| b.contains([x, y, z])).count();
                        assert_eq!(n, 1, "{parts} parts: cell {x},{y},{z}");
                    }
                }
            }
            let (lo, hi) = (per.iter().min().unwrap(), per.iter().max().unwrap());
            assert!(*hi <= 2 * lo.max(&1) + 16, "{parts} parts: {per:?}");
        }
        // Weights move the cut: all the weight in the first two slabs along x.
        let mut w = vec![0.0; 128];
        for z in 0..4 {
            for y in 0..4 {
                for x in 0..2 {
                    w[x + 8 * (y + 4 * z)] = 1.0;
                }
            }
        }
        let boxes = kd_split(counts, &w, 2);
        assert_eq!(boxes[0].hi[0], 1, "{boxes:?}");
        // Front to back: from an eye left of the grid along x, the left box first.
        let tree = KdTree::new(counts, &[], 2);
        assert_eq!(tree.order([-5.0, 2.0, 2.0]), [0, 1]);
        assert_eq!(tree.order([50.0, 2.0, 2.0]), [1, 0]);
        let tree = KdTree::new(counts, &[], 4);
        let order = tree.order([-5.0, -5.0, -5.0]);
        assert_eq!(order[0], 0, "{order:?}");
        assert_eq!(order[3], 3, "{order:?}");
        // More ranks than cells: the rest get empty boxes.
        let boxes = kd_split([1, 1, 2], &[], 4);
        assert_eq!(
            boxes
                .iter()
                .filter(|b| b.lo != b.hi && (0..3).all(|a| b.lo[a] < b.hi[a]))
                .count(),
            2
        );
    }

    #[test]
    fn a_solo_team_agrees_with_itself() {
        let t: &dyn Team = &Solo;
        assert!(t.same_inputs(7).is_ok());
        let e = t
            .agree(Err(Error::Invalid("a chunk is corrupt".into())))
            .unwrap_err();
        assert_eq!(e.to_string(), "a chunk is corrupt");
        assert_eq!(t.min_max([1.0, 2.0]), [1.0, 2.0]);
    }
}
