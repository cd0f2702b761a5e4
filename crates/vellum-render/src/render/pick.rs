//! Picking (issue 42): which segment a pixel of a ray-cast frame shows, for the viewer's click.
//!
//! The ray of a pixel is the ray caster's (`raycast.comp`: the pixel's centre unprojected at the
//! near and far planes, in the box frame), walked on the host through the volume and its label
//! volume half a voxel at a time. Each sample takes its transfer function's opacity at the
//! volume's trilinear value (corrected for the step) and its segment's visibility from the
//! label table, nearest; a hidden segment adds nothing. The pick is the segment of the sample at
//! which the accumulated opacity passes one half: the surface that dominates the pixel. A ray
//! that never gets there picks the segment that gave it the most opacity, and one that gathers
//! less than [`MIN_OPACITY`] picks nothing.

use crate::classify::labels::{LabelSpec, SCREENED, SHOWN};
use crate::classify::transfer::TransferFunction;
use crate::render::view::{FrameCamera, View, WorldBox};
use glam::{Vec3, Vec4};
use vellum_volume::labels::Labels;
use vellum_volume::Volume;

/// Opacity a ray must gather for its pixel to show a segment.
pub const MIN_OPACITY: f32 = 0.05;

/// What a pick walks through: the volume with its value range and transfer function, and its
/// segments as `spec` draws them (`background`: whether id 0 is drawn, as [`LabelSpec::table`]).
pub struct PickInput<'a> {
    /// The volume on the host.
    pub volume: &'a Volume,
    /// The values the transfer function's domain spans.
    pub range: [f64; 2],
    /// The transfer function.
    pub tf: &'a TransferFunction,
    /// The label volume, on the volume's grid.
    pub labels: &'a Labels,
    /// Which segments are drawn.
    pub spec: &'a LabelSpec,
    /// Whether id 0 is drawn unless hidden.
    pub background: bool,
}

/// The id of the segment that pixel `pixel` (from the top left, in pixels of `view.size`) of a
/// frame of `view` shows, or `None` where the ray meets no visible segment.
pub fn pick_label(input: &PickInput, view: &View, pixel: [f32; 2]) -> Option<u32> {
    let v = input.volume;
    let world = WorldBox::new(v.dims, v.spacing, &v.geometry);
    let camera = FrameCamera::new(&world, view);
    let size = view.size.map(|s| s.max(1) as f32);
    let ndc = [0, 1].map(|a| (pixel[a] + 0.5) / size[a] * 2.0 - 1.0);
    let inv = camera.view_proj.inverse();
    let at = |z: f32| {
        let p = inv * Vec4::new(ndc[0], ndc[1], z, 1.0);
        p.truncate() / p.w
    };
    let (o, far) = (at(0.0), at(1.0));
    let dir = (far - o).normalize_or_zero();
    let (t_in, t_out) = box_span(o, dir, world.half)?;
    let table = input.spec.table(input.labels, input.background);
    let step = 0.5 * world.voxel as f32;
    let ratio = 0.5;
    let span = (input.range[1] - input.range[0]).max(f64::MIN_POSITIVE);
    let mut gathered = 0.0f32;
    let mut most: Vec<f32> = vec![0.0; input.labels.ids.len()];
    let mut t = t_in + 0.5 * step;
    while t < t_out {
        let tc = (o + t * dir) / (2.0 * world.half) + 0.5;
        t += step;
        let k = nearest_index(input.labels, tc);
        if table[3 + 2 * k] & SHOWN == 0 || screened(input.labels, &table, tc) {
            continue;
        }
        let x = ((trilinear(v, tc) - input.range[0]) / span) as f32;
        let a = input.tf.sample(x.clamp(0.0, 1.0))[3].clamp(0.0, 1.0);
        let a = 1.0 - (1.0 - a).powf(ratio);
        let add = (1.0 - gathered) * a;
        gathered += add;
        most[k] += add;
        if gathered >= 0.5 {
            return Some(input.labels.ids[k]);
        }
    }
    let (k, &best) = most.iter().enumerate().max_by(|a, b| a.1.total_cmp(b.1))?;
    (best >= MIN_OPACITY).then(|| input.labels.ids[k])
}

/// Where the ray `o + t dir` enters and leaves the box of half extents `half` (t ≥ 0).
fn box_span(o: Vec3, dir: Vec3, half: Vec3) -> Option<(f32, f32)> {
    let inv = dir.recip();
    let (t1, t2) = ((-half - o) * inv, (half - o) * inv);
    let t_in = t1.min(t2).max_element().max(0.0);
    let t_out = t1.max(t2).min_element();
    (t_out > t_in).then_some((t_in, t_out))
}

/// The label index of the voxel holding texture coordinate `tc`.
fn nearest_index(labels: &Labels, tc: Vec3) -> usize {
    let d = labels.dims;
    let i = |a: usize| ((tc[a] * d[a] as f32) as usize).min(d[a] - 1);
    labels.index[i(0) + d[0] * (i(1) + d[1] * i(2))] as usize
}

/// Whether a voxel of a hidden segment is among the eight that linear filtering blends at `tc`
/// (the ray caster's `screened`).
fn screened(labels: &Labels, table: &[u32], tc: Vec3) -> bool {
    let d = labels.dims;
    let c: [i64; 3] = std::array::from_fn(|a| (tc[a] * d[a] as f32 - 0.5).floor() as i64);
    (0..8).any(|k: usize| {
        let v: [usize; 3] = std::array::from_fn(|a| {
            (c[a] + (k >> a & 1) as i64).clamp(0, d[a] as i64 - 1) as usize
        });
        let i = labels.index[v[0] + d[0] * (v[1] + d[1] * v[2])] as usize;
        table[3 + 2 * i] & SCREENED != 0
    })
}

/// The volume's value at texture coordinate `tc`, interpolated between voxel centres (clamped
/// at the edges, as the sampler is).
fn trilinear(v: &Volume, tc: Vec3) -> f64 {
    let p = std::array::from_fn(|a| tc[a] as f64 * v.dims[a] as f64 - 0.5);
    vellum_volume::resample::trilinear_at(|i| v.data.get_f64(i), v.dims, p)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::camera::Camera;
    use vellum_volume::VoxelData;

    /// Two slabs seen from −y (x to the right, z up): ids 3 (x < 8) and 7 (x ≥ 8) where
    /// 4 ≤ z < 12, the intensity their mask.
    fn slabs() -> (Volume, Labels) {
        let n = 16;
        let ids: Vec<u8> = (0..n * n * n)
            .map(|i| match (i % n, i / (n * n)) {
                (_, z) if !(4..12).contains(&z) => 0,
                (x, _) if x < 8 => 3,
                _ => 7,
            })
            .collect();
        let mask = ids.iter().map(|&l| (l > 0) as u8 as f32).collect();
        let lab = Volume::new([n; 3], [1.0; 3], VoxelData::U8(ids)).unwrap();
        let vol = Volume::new([n; 3], [1.0; 3], VoxelData::F32(mask)).unwrap();
        (vol, Labels::of_volume(&lab, "l").unwrap())
    }

    fn view() -> View {
        View {
            camera: Camera::parse("0,0,3").unwrap(),
            size: [100, 100],
            slices: None,
            one_pass: false,
            lighting: Default::default(),
            style: None,
            fit: false,
            raycast: Some(Default::default()),
        }
    }

    #[test]
    fn a_pixel_picks_the_segment_it_shows() {
        let (vol, labels) = slabs();
        let tf = TransferFunction::preset("grey").unwrap();
        let mut spec = LabelSpec::default();
        let input = |spec: &LabelSpec| {
            let i = PickInput {
                volume: &vol,
                range: [0.0, 1.0],
                tf: &tf,
                labels: &labels,
                spec,
                background: true,
            };
            [[40.0, 50.0], [60.0, 50.0], [50.0, 35.0], [2.0, 2.0]]
                .map(|p| pick_label(&i, &view(), p))
        };
        let picks = input(&spec);
        assert_eq!(
            picks[..2],
            [Some(3), Some(7)],
            "left and right of the middle"
        );
        assert_eq!(
            picks[2..],
            [None, None],
            "outside the slabs, and outside the box"
        );
        spec.hide = vec![3];
        assert_eq!(input(&spec)[0], None, "a hidden segment is not picked");
    }
}
