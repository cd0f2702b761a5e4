//! Ambient occlusion by FFT convolution (issue 16), CPU and GPU, on lavapipe with validation on.
//!
//! Tolerances, all on O ∈ [0, 1] in single precision:
//! - against brute force (f64) at R ≤ 6, every voxel of small volumes: max |Δ| ≤ 1e-5 (measured
//!   ≤ 6e-7);
//! - against the runs method at R = 16 and 32 on real volumes: max |Δ| ≤ 1e-5 (runs sums f32
//!   prefix sums, the FFT sums f32 transforms: two different round-offs);
//! - GPU FFT against CPU FFT on the same input: max |Δ| ≤ 1e-5.
//!
//! Borders and corners are where the denominator (the count of in-volume neighbours) goes wrong,
//! so every comparison covers all eight corners and the middles of all twelve edges, and the small
//! cases cover every voxel.

mod common;

use common::{fails_with, vellum, Gpu};
use vellum::passes::occlusion::{
    estimate_ms, normalised_f32, Method, Neighbourhood, Occlusion, OcclusionParams,
};
use vellum::volume::reference::occlusion::{ball_at, gaussian_at, Visibility};
use vellum::volume::{phantom, Volume, VoxelData};

const TOLERANCE: f64 = 1e-5;

fn params(
    radius: u32,
    method: Method,
    neighbourhood: Neighbourhood,
    stride: u32,
) -> OcclusionParams {
    OcclusionParams {
        radius,
        visibility: Visibility::Ramp,
        neighbourhood,
        stride,
        spectrum_bins: None,
        method,
        pad: None,
    }
}

fn occlusion(occ: &mut Occlusion, v: &Volume, p: &OcclusionParams) -> (Vec<f32>, [usize; 3]) {
    let out = occ.compute(v, p).expect("occlusion");
    assert_eq!(out.method, p.method, "the asked method ran");
    let VoxelData::F32(o) = out.occlusion.data else {
        panic!("float occlusion")
    };
    (o, out.occlusion.dims)
}

/// A deterministic volume with structure at every scale, including the borders.
fn noise(dims: [usize; 3]) -> Volume {
    let n = dims.iter().product::<usize>();
    let values: Vec<f32> = (0..n)
        .map(|i| {
            let (x, y, z) = (
                i % dims[0],
                (i / dims[0]) % dims[1],
                i / (dims[0] * dims[1]),
            );
            let h = ((x * 73856093) ^ (y * 19349663) ^ (z * 83492791)) % 1000;
            h as f32 / 999.0
                * if (x / 5 + y / 3 + z / 4) % 2 == 0 {
                    1.0
                } else {
                    0.3
                }
        })
        .collect();
    Volume::new(dims, [1.0; 3], VoxelData::F32(values)).expect("volume")
}

/// All eight corners, the middles of the twelve edges and of the six faces, and the centre of an
/// output grid.
fn border_points(out: [usize; 3]) -> Vec<[usize; 3]> {
    let choices = |n: usize| [0, n / 2, n - 1];
    let mut pts = Vec::new();
    for z in choices(out[2]) {
        for y in choices(out[1]) {
            for x in choices(out[0]) {
                pts.push([x, y, z]);
            }
        }
    }
    pts
}

/// Max |O − brute force| at the output points `pts`.
fn against_brute_force(
    v: &Volume,
    o: &[f32],
    out: [usize; 3],
    p: &OcclusionParams,
    pts: &[[usize; 3]],
) -> f64 {
    let (intensity, _) = normalised_f32(v);
    let s = p.stride as usize;
    let inputs: Vec<[usize; 3]> = pts
        .iter()
        .map(|q| std::array::from_fn(|a| (q[a] * s).min(v.dims[a] - 1)))
        .collect();
    let r = p.radius as i64;
    let reference = match p.neighbourhood {
        Neighbourhood::Ball => ball_at(&intensity, v.dims, &p.visibility, r, &inputs),
        Neighbourhood::Gaussian => gaussian_at(&intensity, v.dims, &p.visibility, r, &inputs),
    };
    pts.iter()
        .zip(&reference)
        .map(|(q, r)| (o[q[0] + out[0] * (q[1] + out[1] * q[2])] as f64 - r).abs())
        .fold(0.0, f64::max)
}

fn max_diff(a: &[f32], b: &[f32]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs() as f64)
        .fold(0.0, f64::max)
}

fn all_points(out: [usize; 3]) -> Vec<[usize; 3]> {
    (0..out.iter().product::<usize>())
        .map(|i| [i % out[0], (i / out[0]) % out[1], i / (out[0] * out[1])])
        .collect()
}

#[test]
fn fft_equals_brute_force_at_small_radii_every_voxel() {
    let gpu = Gpu::new();
    let mut occ = Occlusion::new(&gpu.ctx).unwrap();
    let cases: Vec<(Volume, &str)> = vec![
        (phantom::nested(32), "nested 32³"),
        (noise([23, 17, 9]), "noise 23×17×9"),
        (noise([41, 41, 41]), "noise 41³"),
    ];
    for (v, name) in &cases {
        for r in [1, 3, 6] {
            for nb in [Neighbourhood::Ball, Neighbourhood::Gaussian] {
                for method in [Method::FftCpu, Method::FftGpu] {
                    let p = params(r, method, nb, 1);
                    let (o, out) = occlusion(&mut occ, v, &p);
                    let worst = against_brute_force(v, &o, out, &p, &all_points(out));
                    assert!(
                        worst <= TOLERANCE,
                        "{name} R={r} {nb:?} {method:?}: max |FFT − brute force| = {worst:e}"
                    );
                }
            }
        }
    }
}

#[test]
fn fft_keeps_mappings_and_strides_exact_at_sampled_voxels() {
    let gpu = Gpu::new();
    let mut occ = Occlusion::new(&gpu.ctx).unwrap();
    let v = noise([30, 22, 17]);
    let table: Vec<f32> = (0..256).map(|i| ((i * 37) % 256) as f32 / 255.0).collect();
    for visibility in [
        Visibility::Truncated { t0: 0.2, t1: 0.7 },
        Visibility::Table(table),
    ] {
        for stride in [2, 3] {
            for method in [Method::FftCpu, Method::FftGpu] {
                let p = OcclusionParams {
                    visibility: visibility.clone(),
                    ..params(5, method, Neighbourhood::Ball, stride)
                };
                let (o, out) = occlusion(&mut occ, &v, &p);
                assert_eq!(out, v.dims.map(|d| d.div_ceil(stride as usize)));
                let worst = against_brute_force(&v, &o, out, &p, &all_points(out));
                assert!(
                    worst <= TOLERANCE,
                    "{visibility:?} stride {stride} {method:?}: max |Δ| = {worst:e}"
                );
            }
        }
    }
}

#[test]
fn gpu_fft_equals_cpu_fft_on_odd_sizes_and_radii_beyond_the_volume() {
    let gpu = Gpu::new();
    let mut occ = Occlusion::new(&gpu.ctx).unwrap();
    // (dims, radius): odd sizes, prime sizes, a radius beyond two of the three dimensions.
    let cases = [
        ([41, 41, 41], 9u32),
        ([98, 34, 34], 12),
        ([301, 324, 56], 8),
        ([20, 12, 7], 30),
        ([13, 1, 11], 4),
    ];
    for (dims, r) in cases {
        let v = noise(dims);
        for nb in [Neighbourhood::Ball, Neighbourhood::Gaussian] {
            let (a, out) = occlusion(&mut occ, &v, &params(r, Method::FftCpu, nb, 1));
            let (b, _) = occlusion(&mut occ, &v, &params(r, Method::FftGpu, nb, 1));
            let d = max_diff(&a, &b);
            assert!(
                d <= TOLERANCE,
                "{dims:?} R={r} {nb:?}: max |GPU − CPU| = {d:e}"
            );
            // The borders against brute force, where the count term lives.
            let p = params(r, Method::FftCpu, nb, 1);
            let worst = against_brute_force(&v, &a, out, &p, &border_points(out));
            assert!(
                worst <= TOLERANCE,
                "{dims:?} R={r} {nb:?} borders: {worst:e}"
            );
        }
    }
}

/// A crop of a real volume, as float.
fn crop(v: &Volume, start: [usize; 3], dims: [usize; 3]) -> Volume {
    let mut values = Vec::with_capacity(dims.iter().product());
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                let i = (start[0] + x) + v.dims[0] * ((start[1] + y) + v.dims[1] * (start[2] + z));
                values.push(v.data.get_f64(i) as f32);
            }
        }
    }
    Volume::new(dims, v.spacing, VoxelData::F32(values)).expect("crop")
}

#[test]
fn fft_equals_runs_on_real_volumes_at_large_radii() {
    let Some(fuel) = common::real_volume("fuel") else {
        return;
    };
    let Some(neghip) = common::real_volume("neghip") else {
        return;
    };
    let Some(aneurism) = common::real_volume("aneurism") else {
        return;
    };
    let gpu = Gpu::new();
    let mut occ = Occlusion::new(&gpu.ctx).unwrap();
    let cases = [
        (fuel, "fuel"),
        (neghip, "neghip"),
        (crop(&aneurism, [80, 80, 80], [96, 80, 72]), "aneurism crop"),
    ];
    for (v, name) in &cases {
        for r in [16, 32] {
            let (runs, out) = occlusion(
                &mut occ,
                v,
                &params(r, Method::Runs, Neighbourhood::Ball, 1),
            );
            for method in [Method::FftCpu, Method::FftGpu] {
                let (fft, _) = occlusion(&mut occ, v, &params(r, method, Neighbourhood::Ball, 1));
                let d = max_diff(&runs, &fft);
                assert!(
                    d <= TOLERANCE,
                    "{name} R={r} {method:?}: max |FFT − runs| = {d:e}"
                );
            }
            let p = params(r, Method::FftCpu, Neighbourhood::Ball, 1);
            let worst = against_brute_force(v, &runs, out, &p, &border_points(out));
            assert!(
                worst <= TOLERANCE,
                "{name} R={r} corners against brute force: {worst:e}"
            );
        }
    }
}

#[test]
fn auto_follows_the_cost_model() {
    let gpu = Gpu::new();
    let occ = Occlusion::new(&gpu.ctx).unwrap();
    let ty = gpu.ctx.info.device_type.clone();
    let big = params(64, Method::Auto, Neighbourhood::Ball, 1);
    let tiny = params(1, Method::Auto, Neighbourhood::Ball, 1);
    let chosen = occ.choose([256; 3], &big, false).unwrap();
    let cheapest = [Method::Runs, Method::FftGpu, Method::FftCpu]
        .into_iter()
        .filter(|&m| ty == "CPU" || m != Method::FftCpu)
        .min_by(|&a, &b| {
            estimate_ms(a, &ty, [256; 3], &big).total_cmp(&estimate_ms(b, &ty, [256; 3], &big))
        })
        .unwrap();
    assert_eq!(chosen, cheapest);
    assert_ne!(chosen, Method::Runs, "R = 64 on 256³ must take an FFT");
    assert_eq!(occ.choose([16; 3], &tiny, false).unwrap(), Method::Runs);
    // A recorded frame cannot run the CPU method.
    assert_ne!(occ.choose([256; 3], &big, true).unwrap(), Method::FftCpu);
    // The FFT's cost follows the padded volume, (N + R)³, not the kernel; the runs' grows as R².
    let at = |m, r| {
        estimate_ms(
            m,
            &ty,
            [256; 3],
            &params(r, Method::Auto, Neighbourhood::Ball, 1),
        )
    };
    let points = |r| {
        vellum::passes::occlusion_fft::padded_dims([256; 3], r)
            .iter()
            .map(|&p| p as f64)
            .product::<f64>()
    };
    assert!(at(Method::FftCpu, 100) / at(Method::FftCpu, 16) < 1.1 * points(100) / points(16));
    assert!(at(Method::Runs, 64) > 10.0 * at(Method::Runs, 16));
}

#[test]
fn cli_runs_each_method_and_refuses_what_it_cannot() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("ao.nrrd");
    let o = out.to_str().unwrap();
    for method in ["fft-cpu", "fft-gpu", "auto"] {
        let r = vellum(&[
            "occlusion",
            "phantom:nested:40",
            "--radius",
            "50",
            "--method",
            method,
            "--out",
            o,
            "--json",
        ]);
        assert!(
            r.status.success(),
            "{method}: {}",
            String::from_utf8_lossy(&r.stderr)
        );
        let j: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
        if method != "auto" {
            assert_eq!(j["method"], method);
        }
        assert!(out.exists());
        std::fs::remove_file(&out).unwrap();
    }
    fails_with(
        &vellum(&["occlusion", "phantom:nested:16", "--method", "fast"]),
        "occlusion method 'fast' is unknown",
    );
    // Transforms longer than the GPU method handles: refused with what it needs and the limit.
    let raw = dir.path().join("long.raw");
    std::fs::write(&raw, vec![7u8; 4000 * 2 * 2]).unwrap();
    let r = vellum(&[
        "occlusion",
        raw.to_str().unwrap(),
        "--raw-dims",
        "4000,2,2",
        "--raw-type",
        "uint8",
        "--radius",
        "200",
        "--method",
        "fft-gpu",
        "--out",
        o,
    ]);
    common::fails_with_all(&r, &["fft-gpu", "4320", "at most 4096"]);
    assert!(!out.exists(), "no partial output");
}

#[test]
fn sensitivity_sweeps_to_r100_at_full_resolution_on_the_fast_path() {
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("s.png");
    let csv = dir.path().join("s.csv");
    let r = vellum(&[
        "occlusion-sensitivity",
        "phantom:nested:48",
        "--radii",
        "4,25,100",
        "--out",
        png.to_str().unwrap(),
        "--csv",
        csv.to_str().unwrap(),
    ]);
    let text = String::from_utf8_lossy(&r.stdout);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    assert!(text.contains("stride 1"), "full resolution: {text}");
    let rows = std::fs::read_to_string(&csv).unwrap();
    assert!(rows.lines().any(|l| l.starts_with("100,")));
}

#[test]
fn sizes_beyond_memory_are_refused_with_the_need_and_the_limit() {
    use vellum::passes::occlusion_fft::{
        check_cpu_memory, denominator_entries, gpu::FftGpu, padded_dims,
    };
    let gpu = Gpu::new();
    // 1000³ at R = 64: several GiB of spectra, beyond lavapipe's 2 GiB heap (checked before any
    // allocation).
    let dims = [1000, 1000, 1000];
    let pad = padded_dims(dims, 64);
    let heap = gpu.ctx.info.device_local_heap_bytes;
    if heap < 8 << 30 {
        let e = FftGpu::check(&gpu.ctx, dims, pad, 1, denominator_entries(dims, 64))
            .expect_err("too large for the heap")
            .to_string();
        assert!(
            e.contains("MiB of device memory")
                && e.contains(&format!("{:.0} MiB", heap as f64 / 1048576.0)),
            "{e}"
        );
        assert_eq!(e.lines().count(), 1);
    }
    let e = check_cpu_memory(dims, pad, 1, Some(1 << 30))
        .expect_err("1 GiB is too little")
        .to_string();
    assert!(
        e.contains("fft-cpu would need") && e.contains("1024 MiB are available"),
        "{e}"
    );
    assert!(check_cpu_memory([64; 3], padded_dims([64; 3], 8), 1, Some(1 << 30)).is_ok());
}
