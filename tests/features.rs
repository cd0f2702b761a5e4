//! Feature maps (SPEC FM1–FM6) end to end: the boundary stays put, private intervals are private,
//! categories match counts derived by hand, the real skull mask and a seeded engine valve migrate,
//! and the CLI writes, appends to and prints feature maps.

mod common;

use std::path::Path;
use std::process::{Command, Output};
use std::time::Instant;

use vellum::volume::feature::neighbourhood::Grid;
use vellum::volume::feature::{
    categorise, migrate, Categories, Category, Connectivity, FeatureMap, MigrateParams, Migration,
    Roi,
};
use vellum::volume::io::nrrd::write_nrrd;
use vellum::volume::{Volume, VoxelData, VoxelType};

/// erf(x) after Abramowitz & Stegun 7.1.26 (absolute error below 1.5e-7).
fn erf(x: f64) -> f64 {
    let t = 1.0 / (1.0 + 0.3275911 * x.abs());
    let poly = t
        * (0.254829592
            + t * (-0.284496736 + t * (1.421413741 + t * (-1.453152027 + t * 1.061405429))));
    (1.0 - poly * (-x * x).exp()).copysign(x)
}

/// A smooth step from `below` to `above` at `x0` with a Gaussian edge of `sigma` voxels.
fn edge(x: f64, x0: f64, sigma: f64, below: f64, above: f64) -> f64 {
    below + (above - below) * 0.5 * (1.0 + erf((x - x0) / (sigma * std::f64::consts::SQRT_2)))
}

fn coords(dims: [usize; 3], i: usize) -> [usize; 3] {
    Grid::new(dims).coords(i)
}

fn u8_volume(dims: [usize; 3], f: impl Fn([usize; 3]) -> f64) -> Volume {
    let n = dims.iter().product();
    let data = (0..n)
        .map(|i| f(coords(dims, i)).round().clamp(0.0, 255.0) as u8)
        .collect();
    Volume::new(dims, [1.0; 3], VoxelData::U8(data)).unwrap()
}

fn roi_where(dims: [usize; 3], f: impl Fn([usize; 3]) -> bool) -> Roi {
    let n = dims.iter().product();
    Roi::new(dims, (0..n).map(|i| f(coords(dims, i))).collect()).unwrap()
}

/// Sub-voxel boundary positions along a profile: the maximum of |first derivative| (central
/// differences, parabola through the peak and its neighbours) and the zero crossing of the second
/// derivative nearest to it (linear interpolation).
fn boundary_position(p: &[f64]) -> (f64, f64) {
    let n = p.len();
    let g: Vec<f64> = (1..n - 1)
        .map(|i| (p[i + 1] - p[i - 1]).abs() / 2.0)
        .collect();
    let k = (1..g.len() - 1)
        .max_by(|&a, &b| g[a].total_cmp(&g[b]))
        .unwrap();
    let (a, b, c) = (g[k - 1], g[k], g[k + 1]);
    let denom = a - 2.0 * b + c;
    let grad_max = (k + 1) as f64
        + if denom != 0.0 {
            0.5 * (a - c) / denom
        } else {
            0.0
        };
    let s: Vec<f64> = (1..n - 1)
        .map(|i| p[i + 1] - 2.0 * p[i] + p[i - 1])
        .collect();
    let zero = (0..s.len() - 1)
        .filter_map(|k| {
            if s[k] == 0.0 {
                Some((k + 1) as f64)
            } else if s[k] * s[k + 1] < 0.0 {
                Some((k + 1) as f64 + s[k] / (s[k] - s[k + 1]))
            } else {
                None
            }
        })
        .min_by(|a, b| (a - grad_max).abs().total_cmp(&(b - grad_max).abs()))
        .unwrap();
    (grad_max, zero)
}

/// FM4: a two-material boundary with an erf profile along x keeps its location after migration:
/// the maximum of the gradient and the zero crossing of the second derivative move by less than
/// half a voxel. The edge widths follow the paper's assumption (§3.2) that the fuzzy boundary is
/// 3–4 voxels wide; the edge sits at several sub-voxel offsets. A dark ROI (bone in MRI) is the
/// harder case: eq. 5 turns its profile around; it gets a wide ε so the migrated contrast is large.
#[test]
fn boundary_location_is_kept() {
    let dims = [32, 9, 9];
    let mut worst: f64 = 0.0;
    for (roi_bright, sigma, epsilon) in [
        (true, 0.7, None),
        (true, 1.0, None),
        (false, 0.7, Some(100.0)),
    ] {
        for x0 in [15.0, 15.3, 15.5, 15.8] {
            let vol = u8_volume(dims, |p| edge(p[0] as f64, x0, sigma, 50.0, 200.0));
            let roi = roi_where(dims, |p| {
                let v = vol.data.get_f64(vol.index(p[0], p[1], p[2]));
                (v >= 125.0) == roi_bright
            });
            let params = MigrateParams {
                epsilon,
                ..Default::default()
            };
            let m = migrate(&vol, &roi, &params).unwrap();
            let profile = |v: &Volume| -> Vec<f64> {
                (0..dims[0])
                    .map(|x| v.data.get_f64(v.index(x, 4, 4)))
                    .collect()
            };
            let (g0, z0) = boundary_position(&profile(&vol));
            let (g1, z1) = boundary_position(&profile(&m.volume));
            println!(
                "ROI {} σ={sigma} x0={x0}: gradient max {g0:.3} → {g1:.3}, zero crossing {z0:.3} → {z1:.3} (interval {:?})",
                if roi_bright { "bright" } else { "dark" },
                m.report.interval
            );
            assert!(
                (g1 - g0).abs() < 0.5,
                "gradient maximum moved from {g0} to {g1}"
            );
            assert!(
                (z1 - z0).abs() < 0.5,
                "zero crossing moved from {z0} to {z1}"
            );
            worst = worst.max((g1 - g0).abs()).max((z1 - z0).abs());
            // The ROI did move: its far plateau now lies in the private interval.
            let far = if roi_bright { dims[0] - 2 } else { 1 };
            let v = m.volume.data.get_f64(m.volume.index(far, 4, 4));
            assert!(
                v >= m.report.interval[0] && v <= m.report.interval[1],
                "{v}"
            );
        }
    }
    println!("largest boundary shift: {worst:.3} voxel");
}

/// Two blobs of different intensity with smooth edges and noise.
fn two_blobs() -> (Volume, Roi, Roi) {
    let dims = [40, 32, 32];
    let centres = [[12.0, 16.0, 16.0], [28.0, 16.0, 16.0]];
    let radius = 7.0;
    let dist = |p: [usize; 3], c: [f64; 3]| {
        ((p[0] as f64 - c[0]).powi(2) + (p[1] as f64 - c[1]).powi(2) + (p[2] as f64 - c[2]).powi(2))
            .sqrt()
    };
    // A fixed pseudo-random ±4 of noise per voxel.
    let noise = |p: [usize; 3]| {
        let h = ((p[0] * 73_856_093) ^ (p[1] * 19_349_663) ^ (p[2] * 83_492_791)) % 9;
        h as f64 - 4.0
    };
    let vol = u8_volume(dims, |p| {
        let a = edge(-dist(p, centres[0]), -radius, 0.8, 0.0, 160.0);
        let b = edge(-dist(p, centres[1]), -radius, 0.8, 0.0, 100.0);
        20.0 + a + b + noise(p)
    });
    let a = roi_where(dims, |p| dist(p, centres[0]) <= radius);
    let b = roi_where(dims, |p| dist(p, centres[1]) <= radius);
    (vol, a, b)
}

fn in_interval(v: f64, interval: [f64; 2]) -> bool {
    v >= interval[0] && v <= interval[1]
}

/// Checks that the voxels with values in `m`'s private interval are its ROI or fuzzy boundary,
/// that its categories 2 and 3 lie in the interval, and that category 4 lies below it.
fn check_private(m: &Migration) {
    let iv = m.report.interval;
    let cats: &Categories = &m.categories;
    for i in 0..m.volume.len() {
        let v = m.volume.data.get_f64(i);
        match cats.labels[i] {
            Category::ThinRoi | Category::RoiInterior => {
                assert!(in_interval(v, iv), "ROI voxel {i} = {v} outside {iv:?}")
            }
            Category::Outside => assert!(v < iv[0], "outside voxel {i} = {v} reaches {iv:?}"),
            Category::FuzzyBoundary => {}
        }
        if in_interval(v, iv) {
            assert!(cats.labels[i] != Category::Outside, "voxel {i}");
        }
    }
}

/// FM3/FM5: each private interval holds only its feature (categories 1–3), after one feature and
/// after a second one migrated into the next interval. The one thing a later feature may put into
/// an earlier interval is its own fuzzy boundary, whose eq. 10 values run from its surroundings up
/// to its interval and so cross every interval in between (as any 1D transfer function would see
/// partial-volume voxels).
#[test]
fn private_intervals_are_disjoint() {
    let (vol, roi_a, roi_b) = two_blobs();
    let first = migrate(&vol, &roi_a, &MigrateParams::default()).unwrap();
    let a = first.report.interval;
    assert_eq!(first.report.in_range[1], vol_max(&vol));
    assert!(a[0] > vol_max(&vol), "{a:?}");
    check_private(&first);
    println!(
        "blob a: {:.1}% of its ROI in [{}, {}] (the rest is fuzzy boundary)",
        100.0 * fraction_in(&first.volume, &roi_a, a),
        a[0],
        a[1]
    );

    let second = migrate(&first.volume, &roi_b, &MigrateParams::default()).unwrap();
    let b = second.report.interval;
    assert!(b[0] > a[1], "{b:?} must lie above {a:?}");
    assert_eq!(second.report.in_range[1], vol_max(&first.volume));
    check_private(&second);
    // Interval A after the second migration: A's own voxels, plus B's fuzzy boundary at most.
    for i in 0..vol.len() {
        let v = second.volume.data.get_f64(i);
        if in_interval(v, a) {
            let of_a = first.categories.labels[i] != Category::Outside;
            let b_shell = second.categories.labels[i] == Category::FuzzyBoundary;
            assert!(of_a || b_shell, "voxel {i} = {v} in A's interval {a:?}");
        }
        if first.categories.labels[i].is_roi_body() {
            assert_eq!(second.categories.labels[i], Category::Outside);
            assert_eq!(v, first.volume.data.get_f64(i), "A untouched by B");
        }
    }
    println!(
        "blob b: {:.1}% of its ROI in [{}, {}]",
        100.0 * fraction_in(&second.volume, &roi_b, b),
        b[0],
        b[1]
    );
    // Both intervals still fit 8 bits here, so the output does not widen.
    assert_eq!(second.volume.voxel_type(), VoxelType::U8);

    let mut map = FeatureMap::new(first.report.in_range);
    for (label, m) in [("a", &first), ("b", &second)] {
        let f = vellum::volume::feature::Feature {
            label: label.into(),
            description: String::new(),
            interval: m.report.interval,
            color: map.next_color(),
            source_range: Some(m.report.roi_range),
        };
        map.append(f, Some("blobs")).unwrap();
    }
    let range = [0.0, vol_max(&second.volume)];
    let tf = vellum::classify::features::feature_transfer_function(&map, range).unwrap();
    let mid = |iv: [f64; 2]| tf.sample((0.5 * (iv[0] + iv[1]) / range[1]) as f32);
    assert_eq!(&mid(a)[..3], &vellum::volume::feature::map::PALETTE[0]);
    assert_eq!(&mid(b)[..3], &vellum::volume::feature::map::PALETTE[1]);
}

fn vol_max(v: &Volume) -> f64 {
    vellum::volume::stats::stats(v, 0).max
}

fn fraction_in(v: &Volume, roi: &Roi, interval: [f64; 2]) -> f64 {
    let inside = (0..v.len())
        .filter(|&i| roi.contains(i) && in_interval(v.data.get_f64(i), interval))
        .count();
    inside as f64 / roi.count() as f64
}

fn within(p: [usize; 3], lo: usize, hi: usize) -> bool {
    p.iter().all(|&c| (lo..=hi).contains(&c))
}

/// FM2 on cases small enough to count by hand. Boundary = ROI voxels with a face neighbour
/// outside; type 1 = a boundary voxel with an interior ROI voxel among its 26 neighbours; the
/// fuzzy boundary adds everything 18-adjacent to the boundary.
#[test]
fn category_counts_match_hand_counts() {
    // 3³ cube at 2..=4 in 7³. Boundary: the 26 voxels around the centre, all type 1 (the centre is
    // one of their 26 neighbours). The grow adds the centre (face-adjacent to the face voxels) and,
    // outside, the 5³ block around the cube less the cube (125 − 27 = 98) less its 8 corners, which
    // touch the cube only diagonally in all three axes (not 18-adjacent): 90. Category 1: 26 + 1 +
    // 90 = 117; nothing is left for 2 or 3; category 4: 343 − 117 = 226.
    let c = categorise(&roi_where([7; 3], |p| within(p, 2, 4))).counts();
    assert_eq!(c.as_array(), [117, 0, 0, 226]);

    // 5³ cube at 2..=6 in 9³. Boundary: 125 − 27 (the 3³ core) = 98, all type 1. The grow adds the
    // core less its centre (26) inside, and the 7³ block less the cube less its 8 corners
    // (343 − 125 − 8 = 210) outside. Category 1: 98 + 26 + 210 = 334; category 3: the centre;
    // category 4: 729 − 335 = 394.
    let cube = roi_where([9; 3], |p| within(p, 2, 6));
    let c = categorise(&cube).counts();
    assert_eq!(c.as_array(), [334, 0, 1, 394]);

    // A one-voxel sheet x = 4, 2 <= y, z <= 6 in 9³: all 25 voxels are boundary with no interior
    // anywhere, so type 2 (category 2). The grow adds, on x = 3 and on x = 5, the 5×5 square plus
    // one row along each of its 4 sides (25 + 20 = 45 each; corners of the 7×7 square differ in
    // three coordinates), and in the plane x = 4 the 7×7 square less the sheet (24): 114.
    // Category 4: 729 − 25 − 114 = 590.
    let sheet = roi_where([9; 3], |p| {
        p[0] == 4 && (2..=6).contains(&p[1]) && (2..=6).contains(&p[2])
    });
    let c = categorise(&sheet).counts();
    assert_eq!(c.as_array(), [114, 25, 0, 590]);

    // The same counts come through a migration, and the thin sheet migrates as a whole: its 25
    // voxels (value 200) move by Δ to the bottom of the interval.
    let vol = u8_volume([9; 3], |p| {
        if sheet.contains(p[0] + 9 * (p[1] + 9 * p[2])) {
            200.0
        } else {
            20.0
        }
    });
    let m = migrate(&vol, &sheet, &MigrateParams::default()).unwrap();
    assert_eq!(m.report.categories.as_array(), [114, 25, 0, 590]);
    assert_eq!(m.report.roi_range, [200.0, 200.0]);
    // ε = ⌈5% of 180⌉ = 9: interval [209, 209], Δ = 9.
    assert_eq!((m.report.interval, m.report.delta), ([209.0, 209.0], 9.0));
    assert_eq!(m.volume.data.get_f64(m.volume.index(4, 4, 4)), 209.0);

    // A cube 3 voxels thick is all fuzzy boundary: nothing to migrate, and the error says why.
    let small = roi_where([7; 3], |p| within(p, 2, 4));
    let vol = u8_volume([7; 3], |p| if within(p, 2, 4) { 200.0 } else { 20.0 });
    let e = migrate(&vol, &small, &MigrateParams::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("at least 5 voxels thick"), "{e}");
}

/// The real skull segmentation of the seg3d MRI head migrates; prints the time and counts.
#[test]
fn skull_mask_migrates() {
    let Some(root) = common::shared_data() else {
        return;
    };
    let dir = root.join("volumes/mri_head_seg3d");
    let vol = vellum::volume::io::load(&dir.join("mri_head_seg3d.nhdr"), None).unwrap();
    let mask = vellum::volume::io::load(&dir.join("mri_head_seg3d_skull_mask.nhdr"), None).unwrap();
    let roi = Roi::from_mask(&mask, &vol).unwrap();
    let t = Instant::now();
    let m = migrate(&vol, &roi, &MigrateParams::default()).unwrap();
    let wall = t.elapsed().as_secs_f64();
    let r = &m.report;
    println!(
        "skull: {} ROI voxels, categories {:?}, reconstruction {:?}, interval {:?}, {:?}, {wall:.2} s",
        r.roi_voxels, r.categories, r.reconstruction, r.interval, r.timings
    );
    assert_eq!(r.categories.as_array().iter().sum::<usize>(), vol.len());
    assert_eq!(r.reconstruction.total(), r.categories.fuzzy_boundary);
    assert_eq!(r.interval, [268.0, 523.0]);
    assert_eq!(m.volume.voxel_type(), VoxelType::U16);
    check_private(&m);
    let migrated = fraction_in(&m.volume, &roi, r.interval);
    println!(
        "skull: {:.1}% of the mask lies in the private interval",
        100.0 * migrated
    );
    assert!(migrated > 0.5, "{migrated}");
}

/// Seeded growing picks the engine's valve (head and stem, a component of its own above 160)
/// and migrates it; prints the time.
#[test]
fn engine_valve_by_seeded_growing() {
    let Some(vol) = common::real_volume("engine") else {
        return;
    };
    let t = Instant::now();
    let roi = Roi::grow(
        &vol,
        &[[118, 126, 25]],
        [160.0, 255.0],
        Connectivity::TwentySix,
    )
    .unwrap();
    let grow_ms = t.elapsed().as_secs_f64() * 1e3;
    // Bounding box of the grown region.
    let mut lo = [usize::MAX; 3];
    let mut hi = [0; 3];
    for i in (0..vol.len()).filter(|&i| roi.contains(i)) {
        let p = coords(vol.dims, i);
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    println!(
        "valve: {} voxels in x {}..={}, y {}..={}, z {}..={}",
        roi.count(),
        lo[0],
        hi[0],
        lo[1],
        hi[1],
        lo[2],
        hi[2]
    );
    // The valve: well under 1% of the engine, a few dozen voxels across, in the upper half.
    assert!((20_000..40_000).contains(&roi.count()), "{}", roi.count());
    assert!(
        hi[0] - lo[0] < 90 && hi[1] - lo[1] < 70 && hi[2] < 70,
        "{lo:?} {hi:?}"
    );
    let m = migrate(&vol, &roi, &MigrateParams::default()).unwrap();
    let r = &m.report;
    println!(
        "valve: grow {grow_ms:.1} ms, categories {:?}, interval {:?}, {:?}",
        r.categories, r.interval, r.timings
    );
    check_private(&m);
    assert!(fraction_in(&m.volume, &roi, r.interval) > 0.5);
}

fn vellum(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_vellum"))
        .args(args)
        .env_remove("RUST_BACKTRACE")
        .output()
        .expect("run vellum")
}

/// Asserts failure with one line on stderr, starting "error:" and containing `phrase`.
fn fails_with(out: &Output, phrase: &str) {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "expected failure; stderr: {stderr}");
    assert_ne!(out.status.code(), Some(101), "panicked: {stderr}");
    let lines: Vec<&str> = stderr.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "expected one sentence, got: {stderr}");
    assert!(
        lines[0].starts_with("error: ") && lines[0].contains(phrase),
        "{stderr}"
    );
}

fn succeeds(out: &Output) -> String {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "failed: {stderr}");
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// `vellum migrate` with a mask, then appending a seeded feature to the same map, then
/// `vellum features`; and bad input ending in one sentence.
#[test]
fn cli_migrate_append_and_print() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // Two cubes: A (200) at 4..=11, B (100) at 14..=21, in a background of 10.
    let dims = [24; 3];
    let vol = u8_volume(dims, |p| {
        if within(p, 4, 11) {
            200.0
        } else if within(p, 14, 21) {
            100.0
        } else {
            10.0
        }
    });
    write_nrrd(&d.join("vol.nrrd"), &vol).unwrap();
    let mask = u8_volume(dims, |p| within(p, 4, 11) as u8 as f64);
    write_nrrd(&d.join("mask.nrrd"), &mask).unwrap();
    let (f1, f2, map) = (
        d.join("f1.nrrd"),
        d.join("f2.nrrd"),
        d.join("features.json"),
    );

    let out = succeeds(&vellum(&[
        "migrate",
        s(&d.join("vol.nrrd")),
        "--mask",
        s(&d.join("mask.nrrd")),
        "--label",
        "a",
        "--parent",
        "cubes",
        "--description",
        "the bright cube",
        "--color",
        "1,0,0",
        "--features",
        s(&map),
        "--out",
        s(&f1),
    ]));
    assert!(
        out.contains("times: categorise") && out.contains("created the map"),
        "{out}"
    );
    let first = FeatureMap::load(&map).unwrap();
    let a = first.feature("a").unwrap().interval;
    // IN_high = 200, ε = ⌈0.05 · 190⌉ = 10, ROI range [200, 200].
    assert_eq!(a, [210.0, 210.0]);
    assert_eq!(first.volume.as_deref(), Some("f1.nrrd"));

    let out = succeeds(&vellum(&[
        "migrate",
        s(&f1),
        "--seed",
        "17,17,17;18,18,18",
        "--window",
        "90:110",
        "--connectivity",
        "26",
        "--label",
        "b",
        "--parent",
        "cubes",
        "--features",
        s(&map),
        "--out",
        s(&f2),
        "--json",
    ]));
    let report: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(report["appended"], true);
    assert_eq!(report["report"]["roi_voxels"], 512);
    for key in ["categorise_ms", "migrate_ms", "reconstruct_ms", "total_ms"] {
        assert!(report["report"]["timings"][key].is_number(), "{key}");
    }
    let both = FeatureMap::load(&map).unwrap();
    let b = both.feature("b").unwrap().interval;
    // IN_high = 210 (feature a), ε = ⌈0.05 · 200⌉ = 10, ROI range [100, 100].
    assert_eq!(b, [220.0, 220.0]);
    let f2_vol = vellum::volume::io::load(&f2, None).unwrap();
    assert_eq!(f2_vol.data.get_f64(f2_vol.index(8, 8, 8)), 210.0, "a kept");
    assert_eq!(
        f2_vol.data.get_f64(f2_vol.index(17, 17, 17)),
        220.0,
        "b moved"
    );

    let tree = succeeds(&vellum(&["features", s(&map)]));
    println!("{tree}");
    assert!(tree.contains("└─ cubes/"), "{tree}");
    assert!(
        tree.contains("a  [210, 210]  rgb(1.00, 0.00, 0.00): the bright cube"),
        "{tree}"
    );
    assert!(tree.contains("b  [220, 220]"), "{tree}");

    // Bad input: one sentence each, and nothing written.
    let small = u8_volume([24, 24, 23], |_| 1.0);
    write_nrrd(&d.join("small.nrrd"), &small).unwrap();
    let bad = d.join("bad.nrrd");
    let vol_path = d.join("vol.nrrd");
    let run = |extra: &[&str]| {
        let mut args = vec!["migrate", s(&vol_path), "--label", "c", "--out", s(&bad)];
        args.extend_from_slice(extra);
        vellum(&args)
    };
    fails_with(
        &run(&["--mask", s(&d.join("small.nrrd"))]),
        "expected a mask aligned voxel for voxel",
    );
    fails_with(
        &run(&["--seed", "1,1,1", "--window", "90:110"]),
        "outside the window 90:110",
    );
    fails_with(
        &run(&["--seed", "30,1,1", "--window", "0:255"]),
        "outside the 24x24x24 volume",
    );
    fails_with(
        &run(&["--seed", "1,1", "--window", "0:255"]),
        "expected X,Y,Z",
    );
    fails_with(
        &run(&["--seed", "1,1,1", "--window", "9:1"]),
        "expected LO:HI",
    );
    fails_with(
        &run(&["--mask", s(&d.join("mask.nrrd")), "--features", s(&map)]),
        "above the map's highest interval",
    );
    fails_with(
        &run(&["--mask", s(&d.join("mask.nrrd")), "--color", "255,0,0"]),
        "expected R,G,B",
    );
    let dup = vellum(&[
        "migrate",
        s(&f2),
        "--mask",
        s(&d.join("mask.nrrd")),
        "--label",
        "a",
        "--features",
        s(&map),
        "--out",
        s(&bad),
    ]);
    fails_with(&dup, "exists already");
    assert!(!bad.exists());
    assert_eq!(
        FeatureMap::load(&map).unwrap(),
        both,
        "map untouched by failures"
    );
    fails_with(
        &vellum(&["features", s(&d.join("missing.json"))]),
        "missing.json",
    );
}
