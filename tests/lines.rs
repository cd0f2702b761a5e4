//! Object-space lines (issue 11, SPEC TL5): analytic checks of the CPU reference on smooth
//! phantoms whose f = 0.5 level set is known exactly, and the GPU extraction against it.
//!
//! - A sphere seen orthographically: the silhouette is one closed loop whose projection is a
//!   circle of the sphere's radius (within 0.1 voxel), and there is no suggestive contour, since
//!   κ_r > 0 everywhere on a sphere.
//! - A torus seen along its axis: silhouettes on the outer rim (R + r) and the inner hole (R − r);
//!   seen obliquely, suggestive contours where it is saddle-shaped (the inner half).
//! - A view change moves the silhouette of an ellipsoid.
//! - GPU == CPU: segment counts within 0.5 %, total length within 1 %, Hausdorff < 0.05 voxel,
//!   with the Hessian taken on the fly and read from its precomputed volume.
//! - In a styled frame, a far sphere's silhouette behind a near sphere is culled by the focus
//!   depth, and its silhouette in the open is drawn.

mod common;

use vellum::volume::lines::{extract, Eye, LineParams, Segment, SILHOUETTE, SUGGESTIVE};
use vellum::volume::{phantom, Volume, VoxelData};

fn values(v: &Volume) -> Vec<f32> {
    match &v.data {
        VoxelData::F32(d) => d.clone(),
        _ => panic!("float phantom"),
    }
}

fn params() -> LineParams {
    LineParams {
        iso: 0.5,
        ..LineParams::default()
    }
}

/// Endpoints keyed to 1e-4 voxel that end an odd number of segments. A closed set of curves has
/// none: each endpoint is shared by two segments (four where the curve passes through a vertex
/// of the iso-surface's triangles, whose triangles all contribute).
fn open_ends(segs: &[Segment]) -> usize {
    let mut counts = std::collections::HashMap::new();
    for s in segs {
        for p in [s.a, s.b] {
            let key = [0, 1, 2].map(|i| (p[i] * 1e4).round() as i64);
            *counts.entry(key).or_insert(0) += 1;
        }
    }
    counts.values().filter(|&&c| c % 2 == 1).count()
}

fn of_kind(segs: &[Segment], kind: f32) -> Vec<Segment> {
    segs.iter().copied().filter(|s| s.kind() == kind).collect()
}

fn point_segment(p: [f32; 3], s: &Segment) -> f32 {
    let d: [f32; 3] = std::array::from_fn(|i| s.b[i] - s.a[i]);
    let w: [f32; 3] = std::array::from_fn(|i| p[i] - s.a[i]);
    let dd = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
    let t = if dd > 0.0 {
        ((w[0] * d[0] + w[1] * d[1] + w[2] * d[2]) / dd).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let q: [f32; 3] = std::array::from_fn(|i| s.a[i] + t * d[i] - p[i]);
    (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt()
}

/// Largest distance from any point of `a` (endpoints and midpoints) to the segments of `b`.
/// Segments are bucketed by voxel; a point looks in the buckets around it (segments are shorter
/// than two voxels) and scans everything only when those are empty.
pub fn directed_hausdorff(a: &[Segment], b: &[Segment]) -> f32 {
    let key = |p: [f32; 3]| p.map(|c| c.floor() as i64);
    let mut grid: std::collections::HashMap<[i64; 3], Vec<usize>> = Default::default();
    for (i, s) in b.iter().enumerate() {
        grid.entry(key([s.a[0], s.a[1], s.a[2]]))
            .or_default()
            .push(i);
    }
    a.iter()
        .flat_map(|s| {
            let m: [f32; 3] = std::array::from_fn(|i| 0.5 * (s.a[i] + s.b[i]));
            [[s.a[0], s.a[1], s.a[2]], m, [s.b[0], s.b[1], s.b[2]]]
        })
        .map(|p| {
            let k = key(p);
            let mut best = f32::INFINITY;
            for dz in -2..=2 {
                for dy in -2..=2 {
                    for dx in -2..=2 {
                        if let Some(list) = grid.get(&[k[0] + dx, k[1] + dy, k[2] + dz]) {
                            for &i in list {
                                best = best.min(point_segment(p, &b[i]));
                            }
                        }
                    }
                }
            }
            if best > 1.0 {
                best = b.iter().map(|s| point_segment(p, s)).fold(best, f32::min);
            }
            best
        })
        .fold(0.0, f32::max)
}

#[test]
fn sphere_silhouette_is_one_closed_circle_and_has_no_suggestive_contours() {
    let n = 64;
    let v = phantom::smooth_sphere(n);
    let c = (n - 1) as f32 / 2.0;
    let radius = phantom::SPHERE_RADIUS as f32 * c;
    let segs = extract(
        &values(&v),
        v.dims,
        [1.0; 3],
        Eye::Direction([0.0, 0.0, 1.0]),
        &params(),
    );
    let sil = of_kind(&segs, SILHOUETTE);
    assert!(sil.len() > 100, "{} silhouette segments", sil.len());
    assert_eq!(open_ends(&sil), 0, "the silhouette is closed");
    let mut worst = 0f32;
    for s in &sil {
        for p in [s.a, s.b] {
            let r = ((p[0] - c).powi(2) + (p[1] - c).powi(2)).sqrt();
            worst = worst.max((r - radius).abs());
            // In the plane through the centre, perpendicular to the view.
            assert!(
                (p[2] - c).abs() < 1.0,
                "silhouette point off the equator: {p:?}"
            );
        }
    }
    assert!(worst < 0.1, "projected radius off by {worst} voxel");
    let length: f32 = sil.iter().map(Segment::length).sum();
    let circumference = 2.0 * std::f32::consts::PI * radius;
    assert!(
        (length / circumference - 1.0).abs() < 0.02,
        "length {length} vs {circumference}"
    );
    assert_eq!(
        of_kind(&segs, SUGGESTIVE).len(),
        0,
        "no suggestive contours on a sphere"
    );
}

#[test]
fn torus_has_rim_and_hole_silhouettes_and_suggestive_contours_on_its_saddle() {
    let n = 80;
    let v = phantom::smooth_torus(n);
    let c = (n - 1) as f32 / 2.0;
    let [big, small] = phantom::TORUS_RADII.map(|r| r as f32 * c);
    let vals = values(&v);
    let segs = extract(
        &vals,
        v.dims,
        [1.0; 3],
        Eye::Direction([0.0, 0.0, 1.0]),
        &params(),
    );
    let sil = of_kind(&segs, SILHOUETTE);
    let radii: Vec<f32> = sil
        .iter()
        .map(|s| ((s.a[0] - c).powi(2) + (s.a[1] - c).powi(2)).sqrt())
        .collect();
    let near = |r: f32| radii.iter().filter(|&&x| (x - r).abs() < 0.3).count();
    assert!(near(big + small) > 50, "outer rim: {}", near(big + small));
    assert!(near(big - small) > 20, "inner hole: {}", near(big - small));
    assert_eq!(
        near(big + small) + near(big - small),
        sil.len(),
        "nothing else"
    );
    assert_eq!(open_ends(&sil), 0, "closed loops");
    // Obliquely, suggestive contours appear, and only where the torus is saddle-shaped: the
    // inner half, nearer the axis than the tube's centre circle.
    let oblique = Eye::Direction([0.0, -0.8f32.sin(), 0.8f32.cos()]);
    let segs = extract(&vals, v.dims, [1.0; 3], oblique, &params());
    let sc = of_kind(&segs, SUGGESTIVE);
    assert!(sc.len() > 20, "{} suggestive segments", sc.len());
    for s in &sc {
        let r = ((s.a[0] - c).powi(2) + (s.a[1] - c).powi(2)).sqrt();
        assert!(
            r < big + 0.5,
            "suggestive contour on the convex outer half at r = {r}"
        );
    }
}

#[test]
fn a_view_change_moves_the_silhouette_of_an_ellipsoid() {
    let v = phantom::smooth_ellipsoid(64);
    let vals = values(&v);
    let p = LineParams {
        suggestive: false,
        ..params()
    };
    let a = extract(&vals, v.dims, [1.0; 3], Eye::Direction([0.0, 0.0, 1.0]), &p);
    let b = extract(&vals, v.dims, [1.0; 3], Eye::Direction([0.6, 0.0, 0.8]), &p);
    assert!(!a.is_empty() && !b.is_empty());
    assert!(directed_hausdorff(&a, &b) > 3.0, "the silhouette moved");
    // A perspective eye far away along z approaches the orthographic one.
    let c = 31.5;
    let far = extract(&vals, v.dims, [1.0; 3], Eye::Point([c, c, c + 1e5]), &p);
    assert!(directed_hausdorff(&a, &far) < 0.05 && directed_hausdorff(&far, &a) < 0.05);
    // Anisotropic spacing: a volume squashed 2× along z, with spacing 2, has the same lines.
    let n = 64;
    let squashed: Vec<f32> = (0..n * n * (n / 2))
        .map(|i| vals[(i % (n * n)) + n * n * (2 * (i / (n * n)))])
        .collect();
    let s = extract(
        &squashed,
        [n, n, n / 2],
        [1.0, 1.0, 2.0],
        Eye::Direction([0.6, 0.0, 0.8]),
        &p,
    );
    let stretched: Vec<Segment> = s
        .iter()
        .map(|q| Segment {
            a: [q.a[0], q.a[1], 2.0 * q.a[2], q.a[3]],
            b: [q.b[0], q.b[1], 2.0 * q.b[2], q.b[3]],
        })
        .collect();
    assert!(
        directed_hausdorff(&stretched, &b) < 1.5,
        "spacing respected"
    );
}

/// The CPU reference on the same normalised values and τ the GPU pass sees.
fn cpu_reference(v: &Volume, iso: f32, eye: Eye, p: &LineParams) -> Vec<Segment> {
    let (values, [lo, hi]) = vellum::passes::occlusion::normalised_f32(v);
    let iso = ((iso as f64 - lo) / (hi - lo)) as f32;
    let spacing = v.spacing.map(|s| s as f32);
    extract(&values, v.dims, spacing, eye, &LineParams { iso, ..*p })
}

#[test]
fn gpu_segments_equal_the_cpu_reference() {
    use vellum::passes::lines::{HessianSource, LineExtractor};
    let gpu = common::Gpu::new();
    let mut lines = LineExtractor::new(&gpu.ctx).unwrap();
    let mut pipelines = vellum::gpu::PipelineCache::new(&gpu.ctx);
    let cases: Vec<(Volume, f32, Eye, &str)> = vec![
        (
            phantom::smooth_torus(64),
            0.5,
            Eye::Direction([0.0, -0.8f32.sin(), 0.8f32.cos()]),
            "torus",
        ),
        (
            phantom::smooth_ellipsoid(48),
            0.5,
            Eye::Point([80.0, 20.0, 60.0]),
            "ellipsoid, perspective",
        ),
        (
            phantom::shepp_logan(64),
            0.3,
            Eye::Direction([0.3, 0.5, 0.81]),
            "shepp-logan",
        ),
    ];
    for (v, iso, eye, name) in &cases {
        for stride in [1, 2] {
            let p = LineParams {
                iso: *iso,
                stride,
                ..LineParams::default()
            };
            let got = lines.extract(&mut pipelines, v, *eye, &p, 1 << 20).unwrap();
            assert!(!got.overflowed());
            let want = cpu_reference(v, *iso, *eye, &p);
            assert_same_segments(
                &format!("{name} stride {stride}"),
                &got.segments,
                &want,
                0.05,
            );
        }
        let p = LineParams {
            iso: *iso,
            ..LineParams::default()
        };
        let pre = lines
            .extract_with(
                &mut pipelines,
                v,
                *eye,
                &p,
                1 << 20,
                HessianSource::Precomputed,
            )
            .unwrap();
        assert!(pre.hessian_ms > 0.0, "{name}: the precomputation is timed");
        assert_same_segments(
            &format!("{name}, precomputed Hessian"),
            &pre.segments,
            &cpu_reference(v, *iso, *eye, &p),
            0.05,
        );
    }
}

#[test]
fn an_overflow_is_reported_and_bounded() {
    use vellum::passes::lines::LineExtractor;
    let gpu = common::Gpu::new();
    let mut lines = LineExtractor::new(&gpu.ctx).unwrap();
    let mut pipelines = vellum::gpu::PipelineCache::new(&gpu.ctx);
    let v = phantom::smooth_torus(64);
    let eye = Eye::Direction([0.0, 0.0, 1.0]);
    let full = lines
        .extract(&mut pipelines, &v, eye, &LineParams::default(), 1 << 20)
        .unwrap();
    let small = lines
        .extract(&mut pipelines, &v, eye, &LineParams::default(), 50)
        .unwrap();
    assert!(small.overflowed() && small.segments.len() == 50);
    assert_eq!(
        small.found, full.found,
        "the count goes on past the capacity"
    );
}

/// Two smooth spheres: one nearer the default camera (eye at −y), one farther and larger,
/// overlapping in projection; `near` false leaves the near one out.
fn two_spheres(near: bool) -> Volume {
    let n = 64;
    let sphere = |c: [f32; 3], r: f32, p: [f32; 3]| {
        let d = ((p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2) + (p[2] - c[2]).powi(2)).sqrt();
        0.5 + 0.5 * ((r - d) / 2.5).tanh()
    };
    let values: Vec<f32> = (0..n * n * n)
        .map(|i| {
            let p = [(i % n) as f32, ((i / n) % n) as f32, (i / (n * n)) as f32];
            let far = sphere([44.0, 46.0, 34.0], 12.0, p);
            if near {
                far.max(sphere([26.0, 16.0, 32.0], 11.0, p))
            } else {
                far
            }
        })
        .collect();
    Volume::new([n, n, n], [1.0; 3], VoxelData::F32(values)).unwrap()
}

/// Image size of the visibility test.
const W: usize = 192;

/// A red-silhouette two-level frame of `v`: (composite RGBA, focus linear depth), W².
fn silhouette_frame(gpu: &common::Gpu, v: &Volume) -> (Vec<[f32; 4]>, Vec<f32>) {
    styled_frame(gpu, v, "silhouettes", "0,0,1.8", W as u32)
}

/// A two-level frame of `v` in `style` with red edges over an opaque white focus and a
/// transparent context: (composite RGBA, focus linear depth).
fn styled_frame(
    gpu: &common::Gpu,
    v: &Volume,
    style: &str,
    camera: &str,
    size: u32,
) -> (Vec<[f32; 4]>, Vec<f32>) {
    use vellum::classify::transfer::{ControlPoint, TransferFunction};
    use vellum::classify::{Classification, Focus};
    use vellum::gpu::transfer::readback;
    use vellum::render::style::{Style, StyleParams};
    let ctx = &gpu.ctx;
    // Opaque white focus and a transparent context: the context is composited over the lines,
    // as over every edge, so a visible context would hide them.
    let cp = |x: f32, a: f32| ControlPoint {
        x,
        rgba: [1.0, 1.0, 1.0, a],
    };
    let tf = TransferFunction::new(
        "focus only",
        vec![cp(0.0, 0.0), cp(0.498, 0.0), cp(0.5, 1.0), cp(1.0, 1.0)],
    )
    .unwrap();
    let params = StyleParams {
        edge_color: [1.0, 0.0, 0.0],
        edge_width: 3,
        ..StyleParams::default()
    };
    let (targets, passes) = common::styled_frame(
        ctx,
        v,
        &Classification::Transfer(tf),
        Focus::Iso(0.5),
        camera,
        size,
        Style::new(style, params).unwrap(),
    );
    assert!(passes.iter().any(|p| p.name == "lines_draw"));
    let composite =
        bytemuck::pod_collect_to_vec(&readback(ctx, targets.layer("composite").unwrap()).unwrap());
    let depth = bytemuck::pod_collect_to_vec(
        &readback(ctx, targets.layer("focus.depth").unwrap()).unwrap(),
    );
    (composite, depth)
}

/// Lines behind the focus surface do not reach the image; the same lines in the open do.
#[test]
fn hidden_lines_are_culled_by_the_focus_depth() {
    let gpu = common::Gpu::new();
    let (a, depth_a) = silhouette_frame(&gpu, &two_spheres(true));
    let (b, depth_b) = silhouette_frame(&gpu, &two_spheres(false));
    let red = |c: [f32; 4]| c[0] > 0.6 && c[1] < 0.25 && c[2] < 0.25;
    let w = W;
    let occluded = |i: usize| depth_a[i] < depth_b[i] - 0.05;
    // Occluded with a margin of two pixels: away from the near sphere's own outline.
    let inner = |i: usize| {
        let (x, y) = ((i % w) as i64, (i / w) as i64);
        (-2..=2).all(|dy| {
            (-2..=2).all(|dx| {
                let (u, v) = (x + dx, y + dy);
                u >= 0
                    && v >= 0
                    && u < w as i64
                    && v < w as i64
                    && occluded((v * w as i64 + u) as usize)
            })
        })
    };
    let far_outline: Vec<usize> = (0..w * w).filter(|&i| red(b[i])).collect();
    let hidden: Vec<usize> = far_outline.iter().copied().filter(|&i| inner(i)).collect();
    let open: Vec<usize> = far_outline
        .iter()
        .copied()
        .filter(|&i| (depth_a[i] - depth_b[i]).abs() < 0.01 || !depth_a[i].is_finite())
        .collect();
    assert!(
        hidden.len() > 20,
        "part of the far outline lies behind the near sphere: {}",
        hidden.len()
    );
    assert!(open.len() > 50, "part lies in the open: {}", open.len());
    let drawn_hidden = hidden.iter().filter(|&&i| red(a[i])).count();
    assert_eq!(drawn_hidden, 0, "hidden silhouette pixels drawn");
    let drawn_open = open.iter().filter(|&&i| red(a[i])).count();
    assert!(
        drawn_open as f64 >= 0.9 * open.len() as f64,
        "visible silhouette pixels drawn: {drawn_open} of {}",
        open.len()
    );
}

/// Runs `vellum lines` with `args` and returns its JSON report.
fn lines_json(args: &[&str]) -> serde_json::Value {
    let mut all = vec!["lines"];
    all.extend_from_slice(args);
    all.push("--json");
    common::ok_json(&common::vellum(&all))
}

#[test]
fn the_lines_command_writes_a_png_and_an_svg_of_the_visible_lines() {
    let dir = tempfile::tempdir().unwrap();
    let p = |n: &str| dir.path().join(n).to_string_lossy().into_owned();
    let torus = [
        "phantom:torus:48",
        "--iso",
        "0.5",
        "--camera",
        "20,35",
        "--size",
        "96x96",
    ];
    let (png, svg) = (p("lines.png"), p("lines.svg"));
    let j = lines_json(&[&torus[..], &["--out", &png, "--svg", &svg]].concat());
    assert!(j["silhouette_segments"].as_u64().unwrap() > 50, "{j}");
    assert!(j["suggestive_segments"].as_u64().unwrap() > 0, "{j}");
    assert_eq!(j["overflowed"], false);
    // One seeded frame from a cold start: part of the same lines, from the sparse seeds.
    let seeded_png = p("seeded.png");
    let seeded = lines_json(&[&torus[..], &["--line-seeded", "--out", &seeded_png]].concat());
    let (s, all) = (
        seeded["segments_found"].as_u64().unwrap(),
        j["segments_found"].as_u64().unwrap(),
    );
    assert!(s > 0 && s < all, "seeded {s} of {all}");
    let svg = std::fs::read_to_string(p("lines.svg")).unwrap();
    assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
    let paths = svg.matches("<path d=\"M").count();
    assert!(paths > 0, "visible paths");
    // Every coordinate lies on the image.
    for path in svg.split("<path d=\"").skip(1) {
        let d = &path[..path.find('"').unwrap()];
        for n in d.split(['M', 'L', ' ']).filter(|t| !t.is_empty()) {
            let v: f32 = n.parse().unwrap();
            assert!((0.0..=96.0).contains(&v), "{v}");
        }
    }
    assert!(image::open(p("lines.png")).is_ok());
    // Only the silhouettes: no suggestive group content.
    let j = lines_json(&[
        "phantom:sphere:40",
        "--iso",
        "0.5",
        "--kind",
        "silhouettes",
        "--size",
        "64x64",
        "--out",
        &p("s.png"),
        "--svg",
        &p("s.svg"),
    ]);
    assert_eq!(j["suggestive_segments"], 0);
    common::fails_with(
        &common::vellum(&[
            "lines",
            "phantom:sphere:16",
            "--iso",
            "0.5",
            "--kind",
            "ridges",
            "--out",
            &p("x.png"),
        ]),
        "--kind \"ridges\" is unknown",
    );
    common::fails_with(
        &common::vellum(&["lines", "phantom:sphere:16", "--out", &p("y.png")]),
        "give a focus",
    );
    assert!(!dir.path().join("x.png").exists() && !dir.path().join("y.png").exists());
    // Lines are drawn in core: a store beyond the GPU budget is refused by the session's rule,
    // in one sentence, before it is read (issue 39).
    let store = common::phantom_store(dir.path(), "s.ome.zarr", "sphere:64", 32);
    let store = store.to_str().unwrap();
    for budget in ["0.5", "4"] {
        let args = ["lines", store, "--iso", "0.5", "--gpu-budget", budget];
        let out = common::vellum(&[&args[..], &["--out", &p("z.png")]].concat());
        match budget {
            "0.5" => common::fails_with(&out, "lines draws the whole volume in core, and"),
            _ => assert!(
                out.status.success(),
                "{}",
                String::from_utf8_lossy(&out.stderr)
            ),
        }
        assert_eq!(dir.path().join("z.png").exists(), budget == "4");
    }
}

/// Reference images of the line styles 4-12 (silhouettes or suggestive contours, alone or with
/// Sobel, DoG or Canny edges, and DoG with Kuwahara) on the torus; regenerate with
/// `VELLUM_UPDATE_REFERENCES=1 cargo test --test lines` and look at each one.
#[test]
fn line_styles_match_reference_images() {
    let gpu = common::Gpu::new();
    let v = phantom::smooth_torus(64);
    for (style, file) in [
        ("4", "lines/torus_style04_silhouettes.png"),
        ("5", "lines/torus_style05_suggestive.png"),
        ("6", "lines/torus_style06_sobel_silhouettes.png"),
        ("7", "lines/torus_style07_dog_silhouettes.png"),
        ("8", "lines/torus_style08_canny_silhouettes.png"),
        ("9", "lines/torus_style09_sobel_suggestive.png"),
        ("10", "lines/torus_style10_dog_suggestive.png"),
        ("11", "lines/torus_style11_canny_suggestive.png"),
        ("12", "lines/torus_style12_dog_suggestive_kuwahara.png"),
    ] {
        let (c, _) = styled_frame(&gpu, &v, style, "20,35,2.2", 160);
        // Over a white background, as the gallery shows them.
        let rgb: Vec<u8> = c
            .iter()
            .flat_map(|p| {
                [0, 1, 2].map(|i| ((p[i] + (1.0 - p[3])).clamp(0.0, 1.0) * 255.0).round() as u8)
            })
            .collect();
        common::check_reference(file, 160, 160, &rgb);
    }
}

#[test]
fn bench_lines_reports_every_kind_and_mode() {
    let j = common::ok_json(&common::vellum(&[
        "bench",
        "lines",
        "phantom:torus:32",
        "--iso",
        "0.5",
        "--json",
    ]));
    let rows = j["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 9, "3 kinds × all cells, stride 2 and seeded");
    for r in rows {
        let (g, c) = (
            r["gpu_segments"].as_u64().unwrap(),
            r["cpu_segments"].as_u64().unwrap(),
        );
        if r["mode"] == "seeded" {
            // A subset of the full set at its view, nearly all of it after a turn of 3°.
            let f = r["length_fraction"].as_f64().unwrap();
            assert!(g <= c + 2 && f > 0.9, "{r}");
            continue;
        }
        assert!(g.abs_diff(c) <= (c / 100).max(2), "{r}");
        // The precomputed Hessian holds the same differences: the same segments.
        assert_eq!(r["precomputed_segments"].as_u64(), Some(g), "{r}");
        assert!(r["hessian_ms"].as_f64().unwrap() > 0.0, "{r}");
    }
    let full = rows[0]["gpu_segments"].as_u64().unwrap();
    let interactive = rows[1]["gpu_segments"].as_u64().unwrap();
    assert!(
        interactive > 0 && interactive < full,
        "every other cell finds fewer: {interactive} of {full}"
    );
}

/// `v` with deterministic noise of ±`amp` (a hash per voxel), as measured data has.
fn with_noise(v: &Volume, amp: f32) -> Volume {
    let noisy: Vec<f32> = values(v)
        .iter()
        .enumerate()
        .map(|(i, &x)| {
            let mut h = (i as u32).wrapping_mul(0x9E37_79B9) ^ 0x85EB_CA6B;
            h ^= h >> 16;
            h = h.wrapping_mul(0x7FEB_352D);
            h ^= h >> 15;
            x + amp * ((h >> 8) as f32 / 8_388_608.0 - 1.0)
        })
        .collect();
    Volume::new(v.dims, v.spacing, VoxelData::F32(noisy)).unwrap()
}

/// A block of a real volume, as float.
fn crop(v: &Volume, from: [usize; 3], size: [usize; 3]) -> Volume {
    let mut out = Vec::with_capacity(size.iter().product());
    for z in 0..size[2] {
        for y in 0..size[1] {
            for x in 0..size[0] {
                let i = (from[0] + x) + v.dims[0] * ((from[1] + y) + v.dims[1] * (from[2] + z));
                out.push(v.data.get_f64(i) as f32);
            }
        }
    }
    Volume::new(size, v.spacing, VoxelData::F32(out)).unwrap()
}

/// GPU and CPU segment sets of `v` agree: counts per kind within 0.5 %, total length within 1 %,
/// Hausdorff distance below `hausdorff` voxel.
fn assert_same_segments(name: &str, got: &[Segment], want: &[Segment], hausdorff: f32) {
    for kind in [SILHOUETTE, SUGGESTIVE] {
        let (g, w) = (of_kind(got, kind), of_kind(want, kind));
        let (lg, lw): (f32, f32) = (
            g.iter().map(Segment::length).sum(),
            w.iter().map(Segment::length).sum(),
        );
        assert!(
            g.len().abs_diff(w.len()) <= (w.len() / 200).max(2),
            "{name} kind {kind}: {} vs {}",
            g.len(),
            w.len()
        );
        assert!(
            (lg - lw).abs() <= 0.01 * lw.max(1.0),
            "{name} kind {kind}: length {lg} vs {lw}"
        );
        if !w.is_empty() {
            let h = directed_hausdorff(&g, &w).max(directed_hausdorff(&w, &g));
            assert!(h < hausdorff, "{name} kind {kind}: Hausdorff {h} voxel");
        }
    }
}

/// Smoothing before extraction (`LineParams::smooth`): on noisy data, noise makes κ_r cross zero
/// all over the surface and suggestive contours turn to speckle; the Gaussian brings their count
/// back to near the clean surface's. The GPU passes smooth as the CPU reference does, on a noisy
/// phantom and on the CT head's skull.
#[test]
fn smoothing_removes_noise_contours_and_the_gpu_smooths_as_the_cpu() {
    use vellum::passes::lines::LineExtractor;
    use vellum::volume::lines::smoothed;
    let gpu = common::Gpu::new();
    let mut lines = LineExtractor::new(&gpu.ctx).unwrap();
    let mut pipelines = vellum::gpu::PipelineCache::new(&gpu.ctx);
    let eye = Eye::Direction([0.0, -0.8f32.sin(), 0.8f32.cos()]);
    let clean = phantom::smooth_torus(64);
    let noisy = with_noise(&clean, 0.03);
    let cpu = |v: &Volume, iso: f32, smooth: u32| {
        let st = vellum::volume::stats::stats(v, 0);
        let iso_n = ((iso as f64 - st.min) / (st.max - st.min)) as f32;
        let p = LineParams {
            iso: iso_n,
            smooth,
            ..LineParams::default()
        };
        let spacing = v.spacing.map(|s| s as f32);
        extract(&smoothed(v, smooth).unwrap(), v.dims, spacing, eye, &p)
    };
    let (clean_s, noisy_s, smooth_s) = (
        of_kind(&cpu(&clean, 0.5, 0), SUGGESTIVE),
        of_kind(&cpu(&noisy, 0.5, 0), SUGGESTIVE),
        of_kind(&cpu(&noisy, 0.5, 3), SUGGESTIVE),
    );
    let (c0, n0, n3) = (clean_s.len(), noisy_s.len(), smooth_s.len());
    // The clean torus's contours are still found after smoothing, within 2 voxels.
    let kept = directed_hausdorff(&clean_s, &smooth_s);
    eprintln!("suggestive segments: clean {c0}, noisy {n0}, noisy smoothed {n3}; clean to smoothed {kept:.2} voxel");
    assert!(n0 > 10 * c0, "noise should add contours: {n0} against {c0}");
    assert!(
        n3 < n0 / 10 && n3 < 3 * c0,
        "smoothing should remove them: {n3} against {n0} raw and {c0} clean"
    );
    assert!(
        kept < 2.0,
        "smoothing lost the torus's own contours ({kept} voxel)"
    );
    // The GPU blurs in f32 and the CPU in f64: on the CT head's tens of thousands of contour
    // segments a few sit at the D_w κ_r threshold and flip, each within a cell of its
    // neighbours; hence half a voxel there, against 0.05 on the phantom.
    let mut cases = vec![("noisy torus", noisy, 0.5f32, 0.05)];
    if let Some(ct) = common::real_volume("cthead_stanford") {
        cases.push((
            "CT head",
            crop(&ct, [80, 60, 40], [96, 96, 48]),
            1300.0,
            0.5,
        ));
    }
    for (name, v, iso, hausdorff) in cases {
        let p = LineParams {
            iso,
            smooth: 3,
            ..LineParams::default()
        };
        let got = lines.extract(&mut pipelines, &v, eye, &p, 1 << 20).unwrap();
        assert!(!got.overflowed());
        let want = cpu(&v, iso, 3);
        eprintln!(
            "{name}: {} GPU segments, {} CPU",
            got.segments.len(),
            want.len()
        );
        assert!(!want.is_empty(), "{name}: no lines");
        assert_same_segments(name, &got.segments, &want, hausdorff);
    }
}

#[test]
fn bench_lines_resamples_and_refuses_a_bad_size() {
    let j = common::ok_json(&common::vellum(&[
        "bench",
        "lines",
        "phantom:torus:16",
        "--iso",
        "0.5",
        "--resample",
        "24",
        "--json",
    ]));
    let rows = j["rows"].as_array().unwrap();
    assert!(
        rows.iter()
            .all(|r| r["dims"] == serde_json::json!([24, 24, 24])),
        "{j}"
    );
    assert!(rows.iter().any(|r| r["gpu_segments"].as_u64().unwrap() > 0));
    common::fails_with(
        &common::vellum(&["bench", "lines", "--resample", "1"]),
        "--resample 1 is invalid",
    );
}

/// The rasteriser's antialiasing against a brute-force CPU twin: every pixel whose centre lies
/// within one pixel of a visible segment gets 1 − its distance (round caps), the largest where
/// segments overlap, and the pixels of segments behind the focus stay empty. A line between two
/// pixel rows lights both by halves. The image does not depend on the segments' order.
#[test]
fn lines_are_antialiased_by_distance_whatever_their_order() {
    use ash::vk;
    use vellum::gpu::transfer::{readback, upload};
    use vellum::gpu::{Access, Image};
    use vellum::passes::lines::{LineBuffer, LineExtractor, RasterView};
    let gpu = common::Gpu::new();
    let ctx = &gpu.ctx;
    let lines = LineExtractor::new(ctx).unwrap();
    let (w, h) = (64usize, 48usize);
    // Identity box → clip and index → box: index x in [−1, 1] spans the image; depth = z + 10.
    let view = RasterView {
        view_proj: glam::Mat4::IDENTITY.to_cols_array_2d(),
        index_scale: [1.0; 3],
        index_offset: [0.0; 3],
        eye: [0.0, 0.0, -10.0],
        view_dir: [0.0, 0.0, 1.0],
        bias: 0.0,
        value: 1.0,
        floor: 0.0,
    };
    let focus_depth = 10.0f32;
    // Segments in pixel coordinates and z (visible where z ≤ 0).
    let pixel_segments: Vec<([f32; 3], [f32; 3])> = vec![
        ([5.0, 20.5, 0.0], [25.0, 20.5, 0.0]), // along row 20's centres
        ([5.0, 30.0, 0.0], [25.0, 30.0, 0.0]), // between rows 29 and 30
        ([30.0, 5.0, -1.0], [55.0, 40.0, 0.5]), // diagonal, behind the focus past its middle
        ([55.0, 40.0, 0.5], [60.0, 10.0, 0.5]), // behind the focus
        ([40.0, 2.3, 0.0], [41.7, 44.1, 0.0]), // steep
        ([40.0, 2.3, 0.0], [10.2, 9.9, 0.0]),  // sharing an end with it
        ([12.0, 40.0, 0.0], [12.0, 40.0, 0.0]), // a point
    ];
    let to_index = |p: [f32; 3]| {
        [
            p[0] / w as f32 * 2.0 - 1.0,
            p[1] / h as f32 * 2.0 - 1.0,
            p[2],
        ]
    };
    let draw = |order: &[usize]| -> Vec<f32> {
        let mut buffer = LineBuffer::new(ctx, 64).unwrap();
        {
            let bytes = buffer.buffer.mapped_mut().unwrap();
            let n = order.len() as u32;
            let header = [n.div_ceil(64), 1, 1, n];
            bytes[..16].copy_from_slice(bytemuck::cast_slice(&header));
            for (slot, &k) in order.iter().enumerate() {
                let (a, b) = pixel_segments[k];
                let (a, b) = (to_index(a), to_index(b));
                let seg = [a[0], a[1], a[2], 0.0, b[0], b[1], b[2], 0.0];
                let at = 16 + 32 * slot;
                bytes[at..at + 32].copy_from_slice(bytemuck::cast_slice(&seg));
            }
        }
        let usage = vk::ImageUsageFlags::STORAGE
            | vk::ImageUsageFlags::TRANSFER_SRC
            | vk::ImageUsageFlags::TRANSFER_DST;
        let desc =
            vellum::gpu::resources::ImageDesc::new_2d(vk::Format::R32_SFLOAT, [w as u32, h as u32])
                .usage(usage);
        let depth = Image::new(ctx, "focus depth", &desc).unwrap();
        let edges = Image::new(ctx, "edges", &desc.clone().alias(vk::Format::R32_UINT)).unwrap();
        upload(
            ctx,
            &depth,
            bytemuck::cast_slice(&vec![focus_depth; w * h]),
            Access::ComputeRead,
        )
        .unwrap();
        upload(
            ctx,
            &edges,
            bytemuck::cast_slice(&vec![0f32; w * h]),
            Access::ComputeReadWrite,
        )
        .unwrap();
        vellum::gpu::submit_once(ctx, "raster", |f| {
            lines.record_raster(f, &buffer, &view, &depth, &edges)
        })
        .unwrap();
        bytemuck::pod_collect_to_vec(&readback(ctx, &edges).unwrap())
    };
    // The CPU twin, pixel by pixel over every segment.
    let mut want = vec![0f32; w * h];
    for (y, row) in want.chunks_mut(w).enumerate() {
        for (x, px) in row.iter_mut().enumerate() {
            let q = [x as f32 + 0.5, y as f32 + 0.5];
            for &(a, b) in &pixel_segments {
                let d = [b[0] - a[0], b[1] - a[1]];
                let len2 = d[0] * d[0] + d[1] * d[1];
                let s = if len2 > 0.0 {
                    (((q[0] - a[0]) * d[0] + (q[1] - a[1]) * d[1]) / len2).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                let dist = (a[0] + s * d[0] - q[0]).hypot(a[1] + s * d[1] - q[1]);
                let z = a[2] + s * (b[2] - a[2]) + 10.0;
                if dist < 1.0 && z <= focus_depth {
                    *px = px.max(1.0 - dist);
                }
            }
        }
    }
    let forward: Vec<usize> = (0..pixel_segments.len()).collect();
    let backward: Vec<usize> = forward.iter().rev().copied().collect();
    let got = draw(&forward);
    let worst = got
        .iter()
        .zip(&want)
        .map(|(g, w)| (g - w).abs())
        .fold(0f32, f32::max);
    assert!(
        worst < 1e-3,
        "coverage differs from the CPU twin by {worst}"
    );
    assert_eq!(got, draw(&backward), "the order of the segments matters");
    // Row 20's centre line: full coverage there, none beside it; between rows 29 and 30, halves.
    let at = |x: usize, y: usize| got[y * w + x];
    assert!((at(15, 20) - 1.0).abs() < 1e-5 && at(15, 19) == 0.0 && at(15, 21) == 0.0);
    assert!((at(15, 29) - 0.5).abs() < 1e-5 && (at(15, 30) - 0.5).abs() < 1e-5);
    // The segment behind the focus left nothing.
    assert_eq!(at(58, 25), 0.0);
    assert!(want.iter().filter(|&&v| v > 0.0).count() > 200);
}

/// Total length of `segs` and whether each is one of `full`'s (the same cell's arithmetic gives
/// the same segment), without repeats.
fn subset_length(name: &str, segs: &[Segment], full: &[Segment]) -> (f32, f32) {
    let key = |s: &Segment| -> [i64; 6] {
        let q = |x: f32| (x * 1e3).round() as i64;
        [
            q(s.a[0]),
            q(s.a[1]),
            q(s.a[2]),
            q(s.b[0]),
            q(s.b[1]),
            q(s.b[2]),
        ]
    };
    // Counted: two tiny segments of neighbouring tetrahedra can round to one key.
    let mut left = std::collections::HashMap::new();
    for s in full {
        *left.entry(key(s)).or_insert(0usize) += 1;
    }
    for s in segs {
        let n = left.get_mut(&key(s));
        assert!(
            n.as_ref().is_some_and(|n| **n > 0),
            "{name}: a segment the full extraction lacks, or one drawn twice: {s:?}"
        );
        if let Some(n) = n {
            *n -= 1;
        }
    }
    (
        segs.iter().map(Segment::length).sum(),
        full.iter().map(Segment::length).sum(),
    )
}

/// The seeded traversal (Burns et al.; the interactive mode): its segments are the full
/// extraction's, each once. From a cold start it finds lines from its sparse seeds alone and
/// completes them over frames at a fixed view (the torus's at once); while the view turns 3° a
/// frame, seeded from the frame before, it keeps at least 95 % of each frame's full length.
#[test]
fn the_seeded_traversal_follows_the_lines_from_frame_to_frame() {
    use vellum::passes::lines::LineExtractor;
    let gpu = common::Gpu::new();
    let mut lines = LineExtractor::new(&gpu.ctx).unwrap();
    let mut pipelines = vellum::gpu::PipelineCache::new(&gpu.ctx);
    let eye_at = |deg: f32| {
        let (a, e) = (deg.to_radians(), 0.6f32);
        Eye::Direction([a.sin() * e.cos(), -a.cos() * e.cos(), e.sin()])
    };
    let mut cases = vec![(phantom::smooth_torus(64), 0.5f32, 0usize, "torus")];
    if let Some(ct) = common::real_volume("cthead_stanford") {
        cases.push((
            crop(&ct, [60, 40, 30], [128, 128, 64]),
            1300.0,
            3,
            "CT head",
        ));
    }
    for (v, iso, smooth, name) in cases {
        let base = LineParams {
            iso,
            smooth: smooth as u32,
            ..LineParams::default()
        };
        let seeded = LineParams {
            seeded: true,
            ..base
        };
        // Cold start, fixed view.
        let cold: Vec<(Eye, LineParams)> = (0..6).map(|_| (eye_at(10.0), seeded)).collect();
        let got = lines
            .extract_frames(&mut pipelines, &v, &cold, 1 << 20)
            .unwrap();
        let full = lines
            .extract_frames(&mut pipelines, &v, &[(eye_at(10.0), base)], 1 << 20)
            .unwrap();
        let mut previous = 0.0;
        for (i, f) in got.iter().enumerate() {
            let (l, lf) = subset_length(name, &f.segments, &full[0].segments);
            eprintln!("{name} cold frame {i}: {:.1} % of the full length, {} of {} segments, {:.1} ms against {:.1} ms",
                100.0 * l / lf, f.segments.len(), full[0].segments.len(), f.ms, full[0].ms);
            assert!(
                l >= previous - 1e-3,
                "{name}: frame {i} lost lines at a fixed view"
            );
            previous = l;
            if i == 0 {
                assert!(l > 0.0, "{name}: the seeds alone found nothing");
            }
        }
        let full_length: f32 = full[0].segments.iter().map(Segment::length).sum();
        eprintln!(
            "{name}: cold start reaches {:.1} %",
            100.0 * previous / full_length
        );
        // The torus's four long lines are all near some seed; the CT head's many short
        // fragments are not (about half of their length is found, BENCHMARKS.md).
        if name == "torus" {
            assert!(
                previous >= 0.99 * full_length,
                "{name}: the seeds missed a line"
            );
        }
        // Turning 3° a frame after one full frame.
        let frames: Vec<(Eye, LineParams)> = (0..6)
            .map(|i| {
                (
                    eye_at(10.0 + 3.0 * i as f32),
                    if i == 0 { base } else { seeded },
                )
            })
            .collect();
        let got = lines
            .extract_frames(&mut pipelines, &v, &frames, 1 << 20)
            .unwrap();
        for (i, f) in got.iter().enumerate().skip(1) {
            let full = lines
                .extract(&mut pipelines, &v, frames[i].0, &base, 1 << 20)
                .unwrap();
            let (l, lf) = subset_length(name, &f.segments, &full.segments);
            eprintln!(
                "{name} turning frame {i}: {:.1} % of the full length, {:.1} ms against {:.1} ms",
                100.0 * l / lf,
                f.ms,
                full.ms
            );
            assert!(l >= 0.95 * lf, "{name}: frame {i} kept {l} of {lf}");
        }
    }
}

/// `--line-smooth auto`, the default (issue 29): a smooth sphere stored as uint8 gets no
/// suggestive contours (thousands unsmoothed, from the quantisation step), while the float torus
/// is not smoothed and keeps its reference lines exactly.
#[test]
fn line_smoothing_auto_smooths_quantised_data_only() {
    use vellum::volume::lines::auto_smooth_radius;
    let float = phantom::smooth_sphere(128);
    let bytes: Vec<u8> = values(&float)
        .iter()
        .map(|&x| (x.clamp(0.0, 1.0) * 255.0).round() as u8)
        .collect();
    let quantised = Volume::new(float.dims, float.spacing, VoxelData::U8(bytes)).unwrap();
    assert_eq!(auto_smooth_radius(&float), 0);
    assert!(auto_smooth_radius(&quantised) >= 1);
    assert_eq!(auto_smooth_radius(&phantom::smooth_torus(96)), 0);

    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("sphere_u8.nrrd");
    vellum::volume::io::nrrd::write_nrrd(&path, &quantised).unwrap();
    let png = dir.path().join("lines.png");
    let sphere = |smooth: Option<&str>| {
        let mut args = vec![path.to_str().unwrap(), "--iso", "127", "--size", "256x256"];
        args.extend(["--out", png.to_str().unwrap()]);
        if let Some(s) = smooth {
            args.extend(["--line-smooth", s]);
        }
        lines_json(&args)["suggestive_segments"].as_u64().unwrap()
    };
    let (by_default, unsmoothed) = (sphere(None), sphere(Some("0")));
    eprintln!("uint8 sphere: {by_default} suggestive segments by default, {unsmoothed} unsmoothed");
    assert!(
        by_default <= 10,
        "{by_default} suggestive segments on a smooth sphere"
    );
    assert!(
        unsmoothed > 100,
        "the quantisation makes spurious contours ({unsmoothed})"
    );

    let torus = |smooth: Option<&str>| {
        let mut args = vec!["phantom:torus:96", "--iso", "0.5", "--camera", "20,35"];
        args.extend(["--size", "256x256", "--out", png.to_str().unwrap()]);
        if let Some(s) = smooth {
            args.extend(["--line-smooth", s]);
        }
        let j = lines_json(&args);
        (
            j["suggestive_segments"].as_u64().unwrap(),
            j["silhouette_segments"].as_u64().unwrap(),
        )
    };
    let (t_default, t_raw) = (torus(None), torus(Some("0")));
    assert!(
        t_default.0 > 20,
        "the torus keeps its suggestive contours ({t_default:?})"
    );
    assert_eq!(t_default, t_raw, "float data are not smoothed by default");
}
