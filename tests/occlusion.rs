//! The occlusion spectrum on lavapipe with validation on (SPEC OS1–OS3):
//! - ball occlusion matches CPU brute force within 1e-4 of O's range [0, 1], at R ≤ 6 on a phantom
//!   and real data, and at R = 16 on a 64³ volume (the fast O(R²) method against O(R³));
//! - the Gaussian neighbourhood matches its CPU reference within 1e-4;
//! - a coarser output (stride) is exact at the voxels it samples;
//! - on the nested phantom the two equal-intensity spheres fall into two separate clusters of
//!   occlusion, visible as two runs of bins in the spectrum.

mod common;

use common::Gpu;
use vellum::passes::occlusion::{normalised_f32, Neighbourhood, Occlusion, OcclusionParams};
use vellum::volume::reference::occlusion::{ball_at, gaussian_at, spectrum, Visibility};
use vellum::volume::{phantom, Volume, VoxelData};

const TOLERANCE: f64 = 1e-4;

fn params(
    radius: u32,
    visibility: Visibility,
    neighbourhood: Neighbourhood,
    stride: u32,
) -> OcclusionParams {
    OcclusionParams {
        radius,
        visibility,
        neighbourhood,
        stride,
        spectrum_bins: Some([64, 64]),
        method: vellum::passes::occlusion::Method::Runs,
        pad: None,
    }
}

/// Every voxel of small volumes; otherwise a deterministic sample with all eight corners.
fn sample_points(dims: [usize; 3], stride: usize, max: usize) -> Vec<[usize; 3]> {
    let out: [usize; 3] = dims.map(|d| d.div_ceil(stride));
    let n = out[0] * out[1] * out[2];
    let step = n.div_ceil(max).max(1);
    let mut pts: Vec<[usize; 3]> = (0..n)
        .step_by(step)
        .map(|i| [i % out[0], (i / out[0]) % out[1], i / (out[0] * out[1])])
        .collect();
    for c in 0..8 {
        pts.push([
            (c & 1) * (out[0] - 1),
            (c >> 1 & 1) * (out[1] - 1),
            (c >> 2 & 1) * (out[2] - 1),
        ]);
    }
    pts
}

fn check(
    gpu: &Gpu,
    occ: &mut Occlusion,
    name: &str,
    v: &Volume,
    p: &OcclusionParams,
    max_points: usize,
) {
    let out = occ.compute(v, p).expect("occlusion");
    let VoxelData::F32(o) = &out.occlusion.data else {
        panic!("float occlusion")
    };
    let (intensity, _) = normalised_f32(v);
    let stride = p.stride as usize;
    let pts = sample_points(v.dims, stride, max_points);
    let inputs: Vec<[usize; 3]> = pts
        .iter()
        .map(|q| std::array::from_fn(|a| (q[a] * stride).min(v.dims[a] - 1)))
        .collect();
    let reference = match p.neighbourhood {
        Neighbourhood::Ball => ball_at(&intensity, v.dims, &p.visibility, p.radius as i64, &inputs),
        Neighbourhood::Gaussian => {
            gaussian_at(&intensity, v.dims, &p.visibility, p.radius as i64, &inputs)
        }
    };
    let od = out.occlusion.dims;
    let mut worst = 0.0f64;
    for (q, r) in pts.iter().zip(&reference) {
        let got = o[q[0] + od[0] * (q[1] + od[1] * q[2])] as f64;
        worst = worst.max((got - r).abs());
    }
    assert!(
        worst <= TOLERANCE,
        "{name} R={} {:?} stride {stride}: max |GPU − CPU| = {worst:e}",
        p.radius,
        p.visibility
    );
    // The spectrum counts every voxel once and matches the CPU histogram of the GPU occlusion.
    let s = out.spectrum.expect("spectrum");
    assert_eq!(
        s.counts.iter().map(|&c| c as usize).sum::<usize>(),
        v.len(),
        "{name}: spectrum total"
    );
    let cpu = spectrum(&intensity, v.dims, o, od, stride, [64, 64]);
    let differing: usize = s
        .counts
        .iter()
        .zip(&cpu)
        .map(|(a, b)| a.abs_diff(*b) as usize)
        .sum();
    assert!(
        differing <= v.len() / 1000,
        "{name}: spectrum differs from the CPU histogram in {differing} counts"
    );
    let _ = &gpu.ctx;
}

#[test]
fn ball_matches_brute_force_at_small_radii() {
    let gpu = Gpu::new();
    let mut occ = Occlusion::new(&gpu.ctx).unwrap();
    let v = phantom::shepp_logan(30);
    for r in [1, 3, 6] {
        check(
            &gpu,
            &mut occ,
            "shepp-logan 30",
            &v,
            &params(r, Visibility::Ramp, Neighbourhood::Ball, 1),
            usize::MAX,
        );
    }
    check(
        &gpu,
        &mut occ,
        "shepp-logan 30",
        &v,
        &params(
            4,
            Visibility::Truncated { t0: 0.1, t1: 0.4 },
            Neighbourhood::Ball,
            1,
        ),
        usize::MAX,
    );
    let table: Vec<f32> = (0..256)
        .map(|i| if (40..200).contains(&i) { 0.8 } else { 0.05 })
        .collect();
    check(
        &gpu,
        &mut occ,
        "shepp-logan 30",
        &v,
        &params(5, Visibility::Table(table), Neighbourhood::Ball, 1),
        usize::MAX,
    );
    for name in ["nucleon", "silicium"] {
        let Some(v) = common::real_volume(name) else {
            return;
        };
        check(
            &gpu,
            &mut occ,
            name,
            &v,
            &params(6, Visibility::Ramp, Neighbourhood::Ball, 1),
            20_000,
        );
    }
}

#[test]
fn fast_method_matches_brute_force_at_radius_16_on_64_cubed() {
    let gpu = Gpu::new();
    let mut occ = Occlusion::new(&gpu.ctx).unwrap();
    let v = match common::real_volume("fuel") {
        Some(v) => v,
        None => phantom::shepp_logan(64),
    };
    assert_eq!(v.dims, [64, 64, 64]);
    check(
        &gpu,
        &mut occ,
        "64³",
        &v,
        &params(16, Visibility::Ramp, Neighbourhood::Ball, 1),
        3000,
    );
    check(
        &gpu,
        &mut occ,
        "64³ stride 2",
        &v,
        &params(16, Visibility::Ramp, Neighbourhood::Ball, 2),
        2000,
    );
}

#[test]
fn gaussian_neighbourhood_matches_reference() {
    let gpu = Gpu::new();
    let mut occ = Occlusion::new(&gpu.ctx).unwrap();
    let v = phantom::nested(28);
    check(
        &gpu,
        &mut occ,
        "nested 28",
        &v,
        &params(6, Visibility::Ramp, Neighbourhood::Gaussian, 1),
        usize::MAX,
    );
    check(
        &gpu,
        &mut occ,
        "nested 28 stride 3",
        &v,
        &params(4, Visibility::Ramp, Neighbourhood::Gaussian, 3),
        usize::MAX,
    );
}

#[test]
fn nested_spheres_separate_in_the_spectrum() {
    let gpu = Gpu::new();
    let mut occ = Occlusion::new(&gpu.ctx).unwrap();
    let n = 64;
    let v = phantom::nested(n);
    let bins = 64usize;
    let p = OcclusionParams {
        radius: 12,
        visibility: Visibility::Ramp,
        neighbourhood: Neighbourhood::Ball,
        stride: 1,
        spectrum_bins: Some([bins as u32, bins as u32]),
        method: vellum::passes::occlusion::Method::Runs,
        pad: None,
    };
    let out = occ.compute(&v, &p).unwrap();
    let (VoxelData::F32(d), VoxelData::F32(o)) = (&v.data, &out.occlusion.data) else {
        panic!()
    };
    // Occlusion of the sphere voxels, split by which structure they belong to (x < or > centre).
    let (mut left, mut right) = (Vec::new(), Vec::new());
    for (i, (&s, &occl)) in d.iter().zip(o).enumerate() {
        if s == phantom::NESTED_CORE {
            if i % n < n / 2 {
                left.push(occl)
            } else {
                right.push(occl)
            }
        }
    }
    let range = |x: &[f32]| {
        (
            x.iter().copied().fold(f32::INFINITY, f32::min),
            x.iter().copied().fold(f32::NEG_INFINITY, f32::max),
        )
    };
    let (l, r) = (range(&left), range(&right));
    assert!(!left.is_empty() && !right.is_empty());
    assert!(
        l.1 < r.0,
        "the low-shelled sphere ({l:?}) must be less occluded than the medium-shelled one ({r:?})"
    );
    // In the spectrum: the sphere intensity's column holds two runs of non-empty bins with a gap.
    let s = out.spectrum.unwrap();
    let [lo, hi] = s.intensity_range;
    let col =
        (((phantom::NESTED_CORE as f64 - lo) / (hi - lo) * bins as f64) as usize).min(bins - 1);
    let filled: Vec<bool> = (0..bins).map(|by| s.counts[by * bins + col] > 0).collect();
    let runs = filled.windows(2).filter(|w| !w[0] && w[1]).count() + usize::from(filled[0]);
    assert_eq!(
        runs, 2,
        "two clusters of occlusion at the spheres' intensity: {filled:?}"
    );
}

#[test]
fn bad_parameters_are_errors() {
    let gpu = Gpu::new();
    let mut occ = Occlusion::new(&gpu.ctx).unwrap();
    let v = phantom::nested(8);
    assert!(occ
        .compute(&v, &params(0, Visibility::Ramp, Neighbourhood::Ball, 1))
        .unwrap_err()
        .to_string()
        .contains("radius"));
    assert!(occ
        .compute(&v, &params(2, Visibility::Ramp, Neighbourhood::Ball, 0))
        .unwrap_err()
        .to_string()
        .contains("stride"));
}

/// OS4 in the renderer: with an occlusion transfer function that colours only highly occluded
/// sphere voxels orange, the sphere inside the medium shell (right) turns orange and the one inside
/// the low shell (left) does not, although both have the same intensity.
#[test]
fn occlusion_tf_render_tells_equal_intensities_apart() {
    use vellum::classify::otf::OcclusionTf;
    use vellum::classify::Focus;
    use vellum::passes::normals::Normals;
    use vellum::render::camera::Camera;
    use vellum::render::frame::{RenderParams, Renderer};
    let gpu = Gpu::new();
    let v = phantom::nested(64);
    let otf = OcclusionTf::load(std::path::Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/examples/nested_otf.json"
    )))
    .unwrap();
    let occ = Occlusion::new(&gpu.ctx)
        .unwrap()
        .compute(
            &v,
            &OcclusionParams {
                radius: otf.radius,
                visibility: Visibility::Ramp,
                neighbourhood: Neighbourhood::Ball,
                stride: 1,
                spectrum_bins: None,
                method: vellum::passes::occlusion::Method::Runs,
                pad: None,
            },
        )
        .unwrap();
    let (mut tex, _) = Normals::new(&gpu.ctx).unwrap().prepare(&v).unwrap();
    tex.attach_occlusion(&gpu.ctx, &occ.occlusion).unwrap();
    let params = RenderParams {
        camera: Camera::parse("0,0,2.2").unwrap(),
        size: [96, 96],
        slices: None,
        focus: Focus::None,
        one_pass: true,
        transfer: vellum::classify::transfer::TransferFunction::preset("grey").unwrap(),
        occlusion_tf: Some(otf.table().unwrap()),
    };
    let frame = Renderer::new(&gpu.ctx)
        .unwrap()
        .render(&tex, &params, true)
        .unwrap();
    // Orange-ness (red minus blue) of each half of the image.
    let half = |right: bool| -> f32 {
        frame
            .composite
            .iter()
            .enumerate()
            .filter(|(i, _)| (i % 96 >= 48) == right)
            .map(|(_, p)| p[0] - p[2])
            .sum()
    };
    assert!(
        half(true) > 1.0 && half(true) > 5.0 * half(false).max(0.0),
        "right {} left {}",
        half(true),
        half(false)
    );
}

/// OS6: on the nested phantom, the selected truncated ramp puts its cut-offs between the low
/// (1/3 of the range) and the medium shell (2/3), which is what separates the two spheres, and
/// every candidate is reported with a score.
#[test]
fn adaptive_selection_separates_the_spheres() {
    use vellum::passes::occlusion_analysis::{select, sensitivity};
    let gpu = Gpu::new();
    let mut occ = Occlusion::new(&gpu.ctx).unwrap();
    let v = phantom::nested(40);
    use vellum::passes::occlusion::Method;
    let sel = select(&mut occ, &v, [0.7, 0.8], 8, 1, Method::Runs).unwrap();
    assert_eq!(sel.candidates.len(), 36);
    assert!(sel.candidates.windows(2).all(|w| w[0].score >= w[1].score));
    let b = &sel.best;
    assert!(
        b.t0 >= 0.3 && b.t1 <= 0.7 && b.t0 < 2.0 / 3.0 && b.t1 > 1.0 / 3.0,
        "best {b:?}"
    );
    assert!(
        b.means.last().unwrap() - b.means.first().unwrap() > 0.4,
        "clusters must be far apart: {b:?}"
    );
    // The fast path (FFT on the CPU and on the GPU) scores every candidate the same, to round-off.
    for method in [Method::FftCpu, Method::FftGpu] {
        let fast = select(&mut occ, &v, [0.7, 0.8], 8, 1, method).unwrap();
        assert_eq!((fast.best.t0, fast.best.t1), (b.t0, b.t1), "{method:?}");
        for (a, c) in sel.candidates.iter().zip(&fast.candidates) {
            assert!(
                (a.score - c.score).abs() <= 1e-6 * a.score.abs().max(1e-3),
                "{method:?}"
            );
        }
    }
    // OS7: one row per (radius, band), variances non-negative; the same with the FFT.
    let rows = sensitivity(&mut occ, &v, &[2, 4, 8], 4, 1, Method::Runs).unwrap();
    assert_eq!(rows.len(), 12);
    assert!(rows.iter().all(|r| r.variance >= 0.0) && rows.iter().any(|r| r.variance > 0.0));
    let fast = sensitivity(&mut occ, &v, &[2, 4, 8], 4, 1, Method::FftCpu).unwrap();
    for (a, c) in rows.iter().zip(&fast) {
        assert!((a.variance - c.variance).abs() <= 1e-6, "{a:?} {c:?}");
    }
}
