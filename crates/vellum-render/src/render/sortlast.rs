//! Sort-last compositing of the two levels (issue 27): each rank of a job ray-casts its own box
//! of the volume (`RayOptions::region`) into partial layers, and the partials are composited
//! in visibility order across the ranks ([`composite`]), by direct send or binary swap.
//!
//! A pixel's partial is focus.phong, focus.diffuse and context (premultiplied RGBA) and the
//! focus depth. Front over back (`over`): the focus layers composite with "over", the depth is
//! the nearest region's that has focus, and the context of a region behind one that has focus
//! is dropped: the single process's rule that context counts only in front of the first focus
//! sample. The operator is associative, so any grouping that keeps the order gives the same
//! image. A one-pass frame's partial is its composite in the focus.phong slot.

use crate::render::targets::{FrameImage, Layers};
use crate::render::view::{FrameCamera, View, WorldBox};
use vellum_error::{Error, Result};
use vellum_volume::geometry::Geometry;
use vellum_volume::team::{KdTree, Team};
use vellum_volume::Volume;

/// Floats per pixel of a partial: focus.phong, focus.diffuse, context (RGBA each), focus depth.
pub(crate) const FLOATS: usize = 13;

/// How the partials travel.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum Exchange {
    /// One all-to-all: rank r composites band r of the image from every rank's band r.
    DirectSend,
    /// log2 N rounds of pairwise swaps of half the current piece (N a power of two).
    BinarySwap,
}

impl Exchange {
    /// Parses `direct-send` or `binary-swap`.
    pub fn parse(s: &str) -> Result<Self> {
        match s {
            "direct-send" => Ok(Exchange::DirectSend),
            "binary-swap" => Ok(Exchange::BinarySwap),
            other => Err(Error::Invalid(format!(
                "compositing {other:?} is not known; expected direct-send or binary-swap"
            ))),
        }
    }

    /// Direct send: it takes any number of ranks and was the faster at 4 and 8 ranks at 512²
    /// and 1024²; binary swap was at 2 ranks (BENCHMARKS.md, `bench mpi`).
    pub fn auto(_ranks: usize) -> Self {
        Exchange::DirectSend
    }

    /// The name [`Exchange::parse`] takes.
    pub fn name(self) -> &'static str {
        match self {
            Exchange::DirectSend => "direct-send",
            Exchange::BinarySwap => "binary-swap",
        }
    }
}

/// Edge of a cell of the k-d split of a frame's volume, in voxels.
pub(crate) const CELL: usize = 32;

/// Weight of a cell that holds only background, against 1 for one that holds more: its rays
/// still walk it, but classify nothing and skip it where they can.
pub(crate) const EMPTY_CELL: f64 = 0.25;

/// The weight of each 32³-voxel cell of a grid of `dims` (x fastest), from `coarse`, the grid or
/// any coarser copy of it (a store's small level): 1 where the cell's largest value rises above
/// the copy's smallest by more than 1 % of its range, `EMPTY_CELL` elsewhere.
pub fn cell_weights(coarse: &Volume, dims: [usize; 3]) -> Vec<f64> {
    let counts = dims.map(|n| n.div_ceil(CELL).max(1));
    let c = coarse.dims;
    let [lo, hi] = vellum_volume::stats::value_range(coarse);
    let floor = lo + 0.01 * (hi - lo);
    let mut weights = vec![EMPTY_CELL; counts.iter().product()];
    // The coarse voxels under cell k along axis a.
    let span = |k: usize, a: usize| -> std::ops::Range<usize> {
        let from = (k * CELL * c[a]) / dims[a];
        let to = (((k + 1) * CELL).min(dims[a]) * c[a]).div_ceil(dims[a]);
        from.min(c[a] - 1)..to.clamp(from.min(c[a] - 1) + 1, c[a])
    };
    for (i, w) in weights.iter_mut().enumerate() {
        let k = [
            i % counts[0],
            (i / counts[0]) % counts[1],
            i / (counts[0] * counts[1]),
        ];
        let full = span(k[2], 2).any(|z| {
            span(k[1], 1)
                .any(|y| span(k[0], 0).any(|x| coarse.data.get_f64(coarse.index(x, y, z)) > floor))
        });
        if full {
            *w = 1.0;
        }
    }
    weights
}

/// The ranks' shares of a frame of a volume of `dims`, `spacing` and `geometry` seen by `view`:
/// each rank's region (texture coordinates for `RayOptions::region`, open where it meets the
/// volume's edge) from a k-d split of 32³-voxel cells balanced by `weights` ([`cell_weights`];
/// empty for equal weights), and the ranks front to back.
pub fn regions(
    (dims, spacing, geometry): ([usize; 3], [f64; 3], &Geometry),
    view: &View,
    (ranks, weights): (usize, &[f64]),
) -> (Vec<[[f32; 3]; 2]>, Vec<usize>) {
    let counts = dims.map(|n| n.div_ceil(CELL).max(1));
    let tree = KdTree::new(counts, weights, ranks);
    let edge = |cell: usize, a: usize| -> f32 {
        match (cell * CELL).min(dims[a]) {
            0 => -1.0,
            v if v >= dims[a] => 2.0,
            v => v as f32 / dims[a] as f32,
        }
    };
    let boxes = tree
        .boxes
        .iter()
        .map(|b| {
            let lo = std::array::from_fn(|a| edge(b.lo[a], a));
            let hi = std::array::from_fn(|a| edge(b.hi[a], a));
            [lo, hi]
        })
        .collect();
    let bx = WorldBox::new(dims, spacing, geometry);
    let cam = FrameCamera::new(&bx, view);
    // The eye in cells; a parallel projection's eye far back along the view direction.
    let eye = match cam.camera.ortho {
        true => -cam.view_dir * 1e6 * bx.half.max_element(),
        false => cam.eye,
    };
    let cells: [f64; 3] = std::array::from_fn(|a| {
        (eye[a] / (2.0 * bx.half[a]) + 0.5) as f64 * dims[a] as f64 / CELL as f64
    });
    (boxes, tree.order(cells))
}

/// A frame's partial, pixel by pixel (rows top to bottom).
pub fn pack(frame: &FrameImage) -> Vec<f32> {
    let n = frame.composite.len();
    let mut out = Vec::with_capacity(n * FLOATS);
    for i in 0..n {
        match &frame.layers {
            Some(l) => {
                out.extend(l.focus_phong[i]);
                out.extend(l.focus_diffuse[i]);
                out.extend(l.context[i]);
                out.push(l.focus_depth[i]);
            }
            None => {
                out.extend(frame.composite[i]);
                out.extend([0.0; 8]);
                out.push(f32::INFINITY);
            }
        }
    }
    out
}

/// The composited partial as layers and a composite (context over focus.phong), as the single
/// process's frame holds them; without `two_level`, focus.phong is the composite.
pub fn unpack(partial: &[f32], two_level: bool) -> (Vec<[f32; 4]>, Option<Layers>) {
    let px =
        |i: usize, at: usize| -> [f32; 4] { std::array::from_fn(|c| partial[i * FLOATS + at + c]) };
    let n = partial.len() / FLOATS;
    if !two_level {
        return ((0..n).map(|i| px(i, 0)).collect(), None);
    }
    let layers = Layers {
        focus_phong: (0..n).map(|i| px(i, 0)).collect(),
        focus_diffuse: (0..n).map(|i| px(i, 4)).collect(),
        context: (0..n).map(|i| px(i, 8)).collect(),
        focus_depth: (0..n).map(|i| partial[i * FLOATS + 12]).collect(),
    };
    let composite = (0..n)
        .map(|i| over4(layers.context[i], layers.focus_phong[i]))
        .collect();
    (composite, Some(layers))
}

fn over4(front: [f32; 4], back: [f32; 4]) -> [f32; 4] {
    std::array::from_fn(|c| front[c] + (1.0 - front[3]) * back[c])
}

/// `front` over `back`, pixel by pixel, into `front`.
pub(crate) fn over(front: &mut [f32], back: &[f32]) {
    for (f, b) in front
        .chunks_exact_mut(FLOATS)
        .zip(back.chunks_exact(FLOATS))
    {
        let has_focus = f[12].is_finite();
        for layer in [0, 4] {
            let a = 1.0 - f[layer + 3];
            for c in 0..4 {
                f[layer + c] += a * b[layer + c];
            }
        }
        if !has_focus {
            let a = 1.0 - f[11];
            for c in 8..12 {
                f[c] += a * b[c];
            }
            f[12] = b[12];
        }
    }
}

/// What compositing cost one rank.
#[derive(Clone, Debug, Default)]
pub struct Cost {
    /// Bytes this rank sent to others (its piece's gather to rank 0 included).
    pub bytes_sent: u64,
    /// Wall-clock seconds this rank spent compositing: from the barrier after ray casting through
    /// the gather to rank 0.
    pub seconds: f64,
    /// Of those seconds, the ones spent in `over` (the rest is the exchange and the gather).
    pub over_seconds: f64,
}

/// Composites every rank's `mine` (a partial of `pixels` pixels) in the visibility order
/// `order` (ranks front to back) by `how`; rank 0 gets the whole image, the others `None`.
pub fn composite(
    team: &dyn Team,
    how: Exchange,
    mine: Vec<f32>,
    order: &[usize],
) -> Result<(Option<Vec<f32>>, Cost)> {
    let n = team.size();
    // The ranks finish ray casting at different times: wait for the last, so that the time is
    // the compositing's own, not the imbalance's.
    team.barrier();
    let start = std::time::Instant::now();
    let pixels = mine.len() / FLOATS;
    let (piece, range, mut sent, over_seconds) = match how {
        Exchange::DirectSend => direct_send(team, &mine, order),
        Exchange::BinarySwap if n.is_power_of_two() => binary_swap(team, mine, order),
        Exchange::BinarySwap => {
            return Err(Error::Invalid(format!(
                "binary swap needs a power of two of ranks, not {n}; use direct-send"
            )))
        }
    };
    // Every rank's piece into rank 0, which knows where each one goes.
    let ranges: Vec<(usize, usize)> = (0..n).map(|r| piece_of(how, r, n, pixels)).collect();
    debug_assert_eq!(ranges[team.rank()], range);
    let counts: Vec<usize> = ranges.iter().map(|(a, b)| (b - a) * FLOATS).collect();
    let mut all = vec![0f32; if team.is_root() { pixels * FLOATS } else { 0 }];
    let mut gathered = vec![0f32; if team.is_root() { all.len() } else { 0 }];
    team.gather(&piece, &counts, &mut gathered);
    if !team.is_root() {
        sent += (piece.len() * 4) as u64;
    }
    if !team.is_root() {
        let cost = Cost {
            bytes_sent: sent,
            seconds: start.elapsed().as_secs_f64(),
            over_seconds,
        };
        return Ok((None, cost));
    }
    let mut at = 0;
    for (a, b) in ranges {
        let len = (b - a) * FLOATS;
        all[a * FLOATS..b * FLOATS].copy_from_slice(&gathered[at..at + len]);
        at += len;
    }
    let cost = Cost {
        bytes_sent: sent,
        seconds: start.elapsed().as_secs_f64(),
        over_seconds,
    };
    Ok((Some(all), cost))
}

/// The pixels `[a, b)` rank `r` of `n` holds after compositing by `how`.
fn piece_of(how: Exchange, r: usize, n: usize, pixels: usize) -> (usize, usize) {
    match how {
        Exchange::DirectSend => band(r, n, pixels),
        Exchange::BinarySwap => {
            // Each round halves the piece: the lower rank of a pair keeps the first half.
            let (mut a, mut b) = (0, pixels);
            let mut bit = 1;
            while bit < n {
                let mid = a + (b - a) / 2;
                match r & bit == 0 {
                    true => b = mid,
                    false => a = mid,
                }
                bit <<= 1;
            }
            (a, b)
        }
    }
}

/// Band `r` of `n` equal bands of `pixels`.
fn band(r: usize, n: usize, pixels: usize) -> (usize, usize) {
    (r * pixels / n, (r + 1) * pixels / n)
}

/// Direct send: band r of every rank's partial to rank r, which composites them in order.
fn direct_send(team: &dyn Team, mine: &[f32], order: &[usize]) -> Exchanged {
    let (n, me) = (team.size(), team.rank());
    let pixels = mine.len() / FLOATS;
    let send_counts: Vec<usize> = (0..n)
        .map(|r| {
            let (a, b) = band(r, n, pixels);
            (b - a) * FLOATS
        })
        .collect();
    let (a, b) = band(me, n, pixels);
    let len = (b - a) * FLOATS;
    let mut recv = vec![0f32; len * n];
    team.exchange((mine, &send_counts), (&mut recv, &vec![len; n]));
    let sent = (send_counts.iter().sum::<usize>() - send_counts[me]) as u64 * 4;
    let start = std::time::Instant::now();
    let mut acc = recv[order[0] * len..(order[0] + 1) * len].to_vec();
    for &r in &order[1..] {
        over(&mut acc, &recv[r * len..(r + 1) * len]);
    }
    (acc, (a, b), sent, start.elapsed().as_secs_f64())
}

/// A rank's composited piece, its pixels, the bytes it sent and the seconds spent in [`over`].
type Exchanged = (Vec<f32>, (usize, usize), u64, f64);

/// Binary swap: in round k the ranks that differ in bit k swap halves of their current piece;
/// the pair's two groups are sibling boxes of the k-d split, so one lies wholly in front.
fn binary_swap(team: &dyn Team, mine: Vec<f32>, order: &[usize]) -> Exchanged {
    let (n, me) = (team.size(), team.rank());
    let position: Vec<usize> = {
        let mut p = vec![0; n];
        for (i, &r) in order.iter().enumerate() {
            p[r] = i;
        }
        p
    };
    // The front-most position among the ranks that share `r`'s bits from `bit` up.
    let first = |r: usize, bit: usize| -> usize {
        (0..n)
            .filter(|&q| q / bit == r / bit)
            .map(|q| position[q])
            .min()
            .unwrap_or(0)
    };
    let (mut a, mut b) = (0, mine.len() / FLOATS);
    let mut piece = mine;
    let mut sent = 0u64;
    let mut over_seconds = 0.0;
    let mut bit = 1;
    while bit < n {
        let partner = me ^ bit;
        let mid = (b - a) / 2;
        let (keep, give) = match me & bit == 0 {
            true => ((0, mid), (mid, b - a)),
            false => ((mid, b - a), (0, mid)),
        };
        let mut theirs = vec![0f32; (keep.1 - keep.0) * FLOATS];
        team.swap(
            partner,
            &piece[give.0 * FLOATS..give.1 * FLOATS],
            &mut theirs,
        );
        sent += ((give.1 - give.0) * FLOATS * 4) as u64;
        let mut ours = piece[keep.0 * FLOATS..keep.1 * FLOATS].to_vec();
        // The groups so far: this rank's and the partner's, each of `bit` ranks.
        let start = std::time::Instant::now();
        if first(me, bit) < first(partner, bit) {
            over(&mut ours, &theirs);
        } else {
            over(&mut theirs, &ours);
            ours = theirs;
        }
        over_seconds += start.elapsed().as_secs_f64();
        piece = ours;
        b = a + keep.1;
        a += keep.0;
        bit <<= 1;
    }
    (piece, (a, b), sent, over_seconds)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pixel(fp: f32, ctx: f32, depth: f32) -> Vec<f32> {
        let mut p = vec![0.0; FLOATS];
        p[0] = fp;
        p[3] = fp;
        p[4] = fp;
        p[7] = fp;
        p[8] = ctx;
        p[11] = ctx;
        p[12] = depth;
        p
    }

    #[test]
    fn context_behind_a_nearer_focus_is_dropped() {
        let inf = f32::INFINITY;
        // In front: context only. Behind: focus and context.
        let mut front = pixel(0.0, 0.5, inf);
        over(&mut front, &pixel(0.5, 0.5, 3.0));
        assert_eq!(front[3], 0.5, "focus composites");
        assert_eq!(
            front[11], 0.75,
            "context in front of the first focus counts"
        );
        assert_eq!(front[12], 3.0);
        // In front: focus. Behind: more context, dropped; more focus, kept.
        let mut front = pixel(0.5, 0.2, 1.0);
        over(&mut front, &pixel(0.5, 0.9, 2.0));
        assert_eq!(front[11], 0.2);
        assert_eq!(front[3], 0.75);
        assert_eq!(front[12], 1.0);
    }

    #[test]
    fn the_operator_is_associative() {
        let inf = f32::INFINITY;
        let parts = [
            pixel(0.0, 0.3, inf),
            pixel(0.4, 0.2, 5.0),
            pixel(0.6, 0.7, 9.0),
        ];
        let mut left = parts[0].clone();
        over(&mut left, &parts[1]);
        over(&mut left, &parts[2]);
        let mut bc = parts[1].clone();
        over(&mut bc, &parts[2]);
        let mut right = parts[0].clone();
        over(&mut right, &bc);
        for (l, r) in left.iter().zip(&right) {
            assert!((l - r).abs() < 1e-6, "{left:?} {right:?}");
        }
    }

    #[test]
    fn cells_with_something_in_them_weigh_more() {
        // 64 x 32 x 32: the right half holds a value, the left half only background.
        let dims = [64, 32, 32];
        let data = (0..64 * 32 * 32)
            .map(|i| if i % 64 >= 32 { 5.0 } else { 0.0 })
            .collect();
        let v = Volume::new(dims, [1.0; 3], vellum_volume::VoxelData::F32(data)).unwrap();
        assert_eq!(cell_weights(&v, dims), [EMPTY_CELL, 1.0]);
        // The same from a copy at half the resolution.
        let half = vellum_volume::io::ome_zarr::halve(&v).unwrap();
        assert_eq!(cell_weights(&half, dims), [EMPTY_CELL, 1.0]);
    }

    #[test]
    fn binary_swap_pieces_tile_the_image() {
        for n in [1, 2, 4, 8] {
            let mut pieces: Vec<_> = (0..n)
                .map(|r| piece_of(Exchange::BinarySwap, r, n, 1001))
                .collect();
            pieces.sort();
            assert_eq!(pieces[0].0, 0);
            assert_eq!(pieces[n - 1].1, 1001);
            for w in pieces.windows(2) {
                assert_eq!(w[0].1, w[1].0, "{n}: {pieces:?}");
            }
        }
    }
}
