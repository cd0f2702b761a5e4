//! Geometry against SimpleITK (ITK's own readers, through tests/support/sitk_geometry.py):
//! - the origin and direction vellum reads from every file in ../shared/data/formats equal
//!   SimpleITK's within 1e-4 (spacing too);
//! - after `convert`, `importance`, `occlusion --stride 2` and `migrate`, SimpleITK reads each
//!   output with the input's geometry (the strided occlusion with twice the spacing and the same
//!   physical point for voxel (0,0,0));
//! - a synthetic NRRD rotated 30° about z with a non-zero origin round-trips exactly;
//! - bad geometry gets one sentence: a non-orthogonal or singular direction matrix, a NaN origin,
//!   a NIfTI with both transform codes 0 and negative pixdims, a mask on another grid.
//!
//! SimpleITK comes from pip (`make deps` installs it). Without it the SimpleITK comparisons are
//! skipped with a note, except under CI=true, where its absence fails loudly.

mod common;

use common::vellum;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn ok(out: &Output) -> Value {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap_or(Value::Null)
}

/// SimpleITK's geometry of each path, or None (skipped) when SimpleITK is missing outside CI.
fn sitk(paths: &[&Path]) -> Option<Value> {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/support/sitk_geometry.py");
    let out = Command::new("python3")
        .arg(&script)
        .args(paths)
        .output()
        .expect("run python3");
    if !out.status.success() {
        let err = String::from_utf8_lossy(&out.stderr);
        if err.contains("No module named 'SimpleITK'")
            && std::env::var("CI").as_deref() != Ok("true")
        {
            eprintln!("note: SimpleITK is not installed; skipping (pip install SimpleITK)");
            return None;
        }
        panic!("SimpleITK failed: {err}");
    }
    Some(serde_json::from_slice(&out.stdout).unwrap())
}

fn floats(v: &Value) -> Vec<f64> {
    v.as_array()
        .unwrap()
        .iter()
        .flat_map(|x| match x {
            Value::Array(a) => a.iter().map(|y| y.as_f64().unwrap()).collect::<Vec<_>>(),
            y => vec![y.as_f64().unwrap()],
        })
        .collect()
}

fn assert_close(what: &str, a: &[f64], b: &[f64], tol: f64) {
    assert_eq!(a.len(), b.len(), "{what}");
    for (x, y) in a.iter().zip(b) {
        assert!(
            (x - y).abs() <= tol,
            "{what}: vellum {a:?} vs SimpleITK {b:?}"
        );
    }
}

/// vellum info --json of `path`.
fn info(path: &Path) -> Value {
    ok(&vellum(&["info", path.to_str().unwrap(), "--json"]))
}

fn format_files() -> Option<Vec<PathBuf>> {
    let root = common::shared_data()?.join("formats");
    Some(
        [
            "nifti/stroke_t1.nii.gz",
            "nifti/mr_gd.nii.gz",
            "nifti/ct_avm.nii.gz",
            "nifti/seg3d_mr_head.nii.gz",
            "nrrd/seg3d_skull_mask.nrrd",
            "nrrd/tooth.nrrd",
            "metaimage/HeadMRVolume.mhd",
            "metaimage/frogtissue.mhd",
            "dicom/seg3d_mr_640",
            "dicom/vs_seg001_t1",
        ]
        .iter()
        .map(|f| root.join(f))
        .collect(),
    )
}

#[test]
fn every_reader_agrees_with_simpleitk() {
    let Some(files) = format_files() else {
        return;
    };
    let refs: Vec<&Path> = files.iter().map(PathBuf::as_path).collect();
    let Some(want) = sitk(&refs) else {
        return;
    };
    for f in &files {
        let got = info(f);
        let w = &want[f.to_str().unwrap()];
        let name = f.display().to_string();
        assert_close(
            &format!("{name} origin"),
            &floats(&got["origin"]),
            &floats(&w["origin"]),
            1e-4,
        );
        assert_close(
            &format!("{name} direction"),
            &floats(&got["direction"]),
            &floats(&w["direction"]),
            1e-4,
        );
        assert_close(
            &format!("{name} spacing"),
            &floats(&got["spacing"]),
            &floats(&w["spacing"]),
            1e-4,
        );
    }
    // The oblique NIfTI head: the orientation code says so.
    let stroke = info(&files[0]);
    assert_eq!(stroke["orientation"], "RAS (oblique)");
}

#[test]
fn derived_volumes_keep_the_input_geometry() {
    let Some(root) = common::shared_data() else {
        return;
    };
    let input = root.join("formats/nifti/stroke_t1.nii.gz");
    let dir = tempfile::tempdir().unwrap();
    let p = |n: &str| dir.path().join(n);
    let s = |p: &Path| p.to_str().unwrap().to_string();
    ok(&vellum(&["convert", &s(&input), &s(&p("convert.nrrd"))]));
    ok(&vellum(&[
        "importance",
        &s(&input),
        "--radius",
        "2",
        "--out",
        &s(&p("importance.nrrd")),
    ]));
    ok(&vellum(&[
        "occlusion",
        &s(&input),
        "--radius",
        "2",
        "--stride",
        "2",
        "--out",
        &s(&p("ao.nrrd")),
    ]));
    ok(&vellum(&[
        "migrate",
        &s(&input),
        "--seed",
        "62,80,70",
        "--window",
        "60:252",
        "--label",
        "brain",
        "--out",
        &s(&p("feature.nrrd")),
    ]));
    let outputs = ["convert.nrrd", "importance.nrrd", "ao.nrrd", "feature.nrrd"].map(p);
    let mut all: Vec<&Path> = vec![input.as_path()];
    all.extend(outputs.iter().map(PathBuf::as_path));
    let Some(g) = sitk(&all) else {
        return;
    };
    let src = &g[s(&input).as_str()];
    for out in &outputs {
        let o = &g[s(out).as_str()];
        let name = out.file_name().unwrap().to_string_lossy();
        assert_close(
            &format!("{name} origin"),
            &floats(&o["origin"]),
            &floats(&src["origin"]),
            1e-4,
        );
        assert_close(
            &format!("{name} direction"),
            &floats(&o["direction"]),
            &floats(&src["direction"]),
            1e-6,
        );
        let stride = if name == "ao.nrrd" { 2.0 } else { 1.0 };
        let want_spacing: Vec<f64> = floats(&src["spacing"]).iter().map(|x| x * stride).collect();
        assert_close(
            &format!("{name} spacing"),
            &floats(&o["spacing"]),
            &want_spacing,
            1e-6,
        );
    }
    let ao = &g[s(&outputs[2]).as_str()];
    assert_eq!(floats(&ao["size"]), [62.0, 80.0, 70.0], "strided AO size");
}

#[test]
fn a_rotated_nrrd_round_trips_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let (c, s) = (30f64.to_radians().cos(), 30f64.to_radians().sin());
    let header = format!(
        "NRRD0004\ntype: uint8\ndimension: 3\nspace: left-posterior-superior\nsizes: 4 3 2\n\
         space directions: ({},{},0) ({},{},0) (0,0,2.5)\nspace origin: (-12.5,40.25,7)\n\
         endian: little\nencoding: raw\n\n",
        0.5 * c,
        0.5 * s,
        -0.75 * s,
        0.75 * c
    );
    let path = dir.path().join("rot.nrrd");
    let mut bytes = header.into_bytes();
    bytes.extend((0..24u8).collect::<Vec<_>>());
    std::fs::write(&path, &bytes).unwrap();
    let a = vellum::volume::io::load(&path, None).unwrap();
    assert_eq!(a.spacing, [0.5, 0.75, 2.5]);
    assert_eq!(a.geometry.origin, [-12.5, 40.25, 7.0]);
    assert!((a.geometry.direction[1][0] - s).abs() < 1e-15);
    assert_eq!(a.geometry.orientation_code(), "LPS (oblique)");
    let out = dir.path().join("again.nrrd");
    vellum::volume::io::nrrd::write_nrrd(&out, &a).unwrap();
    let b = vellum::volume::io::load(&out, None).unwrap();
    assert_eq!(a.geometry, b.geometry, "geometry round-trips exactly");
    assert_eq!(a.spacing, b.spacing);
    assert_eq!(a.data, b.data);
    if let Some(g) = sitk(&[&path, &out]) {
        let (x, y) = (&g[path.to_str().unwrap()], &g[out.to_str().unwrap()]);
        assert_close(
            "origin",
            &floats(&x["origin"]),
            &floats(&y["origin"]),
            1e-12,
        );
        assert_close(
            "direction",
            &floats(&x["direction"]),
            &floats(&y["direction"]),
            1e-12,
        );
        assert_close(
            "vellum vs SimpleITK",
            &a.geometry.origin,
            &floats(&x["origin"]),
            1e-12,
        );
    }
}

/// Runs `vellum info FILE` on a file with `bytes`: one sentence containing `phrase`.
fn bad_file(name: &str, bytes: &[u8], phrase: &str) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(name);
    std::fs::write(&path, bytes).unwrap();
    common::fails_with(&vellum(&["info", path.to_str().unwrap()]), phrase);
}

fn nrrd_with(directions: &str, origin: &str) -> Vec<u8> {
    let mut b = format!(
        "NRRD0004\ntype: uint8\ndimension: 3\nspace: left-posterior-superior\nsizes: 2 2 2\n\
         space directions: {directions}\nspace origin: {origin}\nendian: little\nencoding: raw\n\n"
    )
    .into_bytes();
    b.extend([0u8; 8]);
    b
}

#[test]
fn bad_geometry_gets_one_sentence() {
    bad_file(
        "skew.nrrd",
        &nrrd_with("(1,0,0) (1,1,0) (0,0,1)", "(0,0,0)"),
        "not orthonormal",
    );
    bad_file(
        "flat.nrrd",
        &nrrd_with("(1,0,0) (0,0,0) (0,0,1)", "(0,0,0)"),
        "zero or not finite",
    );
    bad_file(
        "nan.nrrd",
        &nrrd_with("(1,0,0) (0,1,0) (0,0,1)", "(nan,0,0)"),
        "origin",
    );
    // NIfTI-1 with qform_code = sform_code = 0 and a negative pixdim.
    let mut h = vec![0u8; 352];
    h[0..4].copy_from_slice(&348i32.to_le_bytes());
    for (i, d) in [3i16, 2, 2, 2, 1, 1, 1, 1].iter().enumerate() {
        h[40 + 2 * i..42 + 2 * i].copy_from_slice(&d.to_le_bytes());
    }
    h[70..72].copy_from_slice(&2i16.to_le_bytes()); // uint8
    h[72..74].copy_from_slice(&8i16.to_le_bytes());
    for (i, p) in [1.0f32, -1.0, 1.0, 1.0].iter().enumerate() {
        h[76 + 4 * i..80 + 4 * i].copy_from_slice(&p.to_le_bytes());
    }
    h[108..112].copy_from_slice(&352f32.to_le_bytes());
    h[344..348].copy_from_slice(b"n+1\0");
    h.extend([0u8; 8]);
    bad_file(
        "neg.nii",
        &h,
        "negative while both qform_code and sform_code are 0",
    );
}

#[test]
fn a_mask_on_another_grid_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let mut data = nrrd_with("(1,0,0) (0,1,0) (0,0,1)", "(0,0,0)");
    let n = data.len();
    data[n - 8..].copy_from_slice(&[10, 20, 30, 40, 50, 60, 70, 80]);
    let mut mask = nrrd_with("(1,0,0) (0,1,0) (0,0,1)", "(3,0,0)");
    let n = mask.len();
    mask[n - 8..].copy_from_slice(&[1, 1, 0, 0, 0, 0, 0, 0]);
    let (d, m) = (dir.path().join("d.nrrd"), dir.path().join("m.nrrd"));
    std::fs::write(&d, data).unwrap();
    std::fs::write(&m, mask).unwrap();
    let out_file = dir.path().join("f.nrrd");
    let out = vellum(&[
        "migrate",
        d.to_str().unwrap(),
        "--mask",
        m.to_str().unwrap(),
        "--label",
        "x",
        "--out",
        out_file.to_str().unwrap(),
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains("does not lie on the volume's grid") && stderr.contains("origin"),
        "{stderr}"
    );
    assert!(!out_file.exists());
}

/// A cube with a marker only at its high-x end, placed so that index x points superior: the
/// default view of an oriented volume (anterior, superior up) shows the marker at the top. The
/// same voxels with no orientation keep the volume's own axes (+z up): the marker is not on top.
#[test]
fn the_superior_end_is_up_by_default() {
    use vellum::classify::modulation::Modulation;
    use vellum::classify::transfer::TransferFunction;
    use vellum::classify::{Classification, Focus};
    use vellum::render::frame::Renderer;
    use vellum::render::scene::{CameraSpec, GpuScene};
    use vellum::render::view::{Lighting, View};
    use vellum::volume::geometry::Geometry;
    use vellum::volume::{Volume, VoxelData};
    let gpu = common::Gpu::new();
    let n = 24usize;
    let data: Vec<f32> = (0..n * n * n)
        .map(|i| {
            let (x, y, z) = (i % n, (i / n) % n, i / (n * n));
            let d = |a: usize, c: f32| (a as f32 - c).powi(2);
            let marker = d(x, 20.0) + d(y, 11.5) + d(z, 11.5) <= 9.0;
            let body = d(x, 11.5) + d(y, 11.5) + d(z, 11.5) <= 36.0;
            if marker {
                1.0
            } else if body {
                0.3
            } else {
                0.0
            }
        })
        .collect();
    let plain = Volume::new([n; 3], [1.0; 3], VoxelData::F32(data)).unwrap();
    // Index x → superior (+z), y → left (+x), z → posterior (+y): a rotation.
    let oriented = plain
        .clone()
        .with_geometry(
            Geometry::lps(
                [10.0, -5.0, 3.0],
                [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
            )
            .unwrap(),
        )
        .unwrap();
    // A transfer function that shows only the marker.
    let tf = TransferFunction::from_json_str(
        r#"{"name": "marker", "points": [{"x": 0.0, "rgba": [1, 1, 1, 0]}, {"x": 0.8, "rgba": [1, 1, 1, 0]}, {"x": 0.9, "rgba": [1, 1, 1, 1]}]}"#,
    )
    .unwrap();
    let mut renderer = Renderer::new(&gpu.ctx).unwrap();
    let mut marker_row = |v: &Volume| {
        let mut scene = GpuScene::prepare(
            &gpu.ctx,
            v,
            &Classification::Transfer(tf.clone()),
            Focus::None,
            &Modulation::default(),
        )
        .unwrap();
        let (camera, fit) = CameraSpec::default()
            .camera(v.geometry.is_oriented())
            .unwrap();
        assert!(fit, "no distance given: the volume is framed");
        let view = View {
            camera,
            size: [64, 64],
            slices: None,
            one_pass: true,
            lighting: Lighting::default(),
            style: None,
            fit,
            raycast: None,
        };
        let f = renderer
            .render_frame(&scene.volume, &mut scene.classify, &view, true)
            .unwrap();
        let (mut sum, mut count) = (0.0, 0.0);
        for (i, p) in f.composite.iter().enumerate() {
            if p[3] > 0.3 {
                sum += (i / 64) as f64;
                count += 1.0;
            }
        }
        assert!(count > 5.0, "the marker shows ({count} px)");
        sum / count
    };
    let up = marker_row(&oriented);
    assert!(
        up < 20.0,
        "oriented: the marker's mean row is {up} of 64, expected near the top"
    );
    let plain_row = marker_row(&plain);
    assert!(
        plain_row > 24.0,
        "unoriented: the marker's mean row is {plain_row}, not on top"
    );
}

/// The default framing fills the image with the volume's box: a long thin box touches the margin
/// on its long side.
#[test]
fn the_default_framing_fits_the_projected_box() {
    use glam::Vec3;
    use vellum::render::camera::Camera;
    let c = Camera {
        azimuth_deg: 0.0,
        elevation_deg: 0.0,
        ..Camera::default()
    };
    let half = Vec3::new(1.0, 0.2, 0.1);
    let corners: Vec<Vec3> = (0..8)
        .map(|i: u32| {
            Vec3::new(
                if i & 1 == 1 { half.x } else { -half.x },
                if i & 2 == 2 { half.y } else { -half.y },
                if i & 4 == 4 { half.z } else { -half.z },
            )
        })
        .collect();
    let radius = half.length();
    let d = c.fit_distance(&corners, radius, 1.0, 0.05);
    let m = Camera { distance: d, ..c }.view_proj(1.0, radius);
    let extent = corners
        .iter()
        .map(|&p| {
            let q = m * p.extend(1.0);
            (q.x / q.w).abs().max((q.y / q.w).abs())
        })
        .fold(0.0f32, f32::max);
    assert!(
        (extent - 0.95).abs() < 1e-3,
        "extent {extent} at distance {d}"
    );
    assert!(d < 2.5, "closer than the bounding-sphere framing: {d}");
}

/// `convert` to `.nii` and `.nii.gz` (NIfTI-1 out, with sform and qform): every real file of
/// ../shared/data/formats, plus a left-handed rotated NRRD (qfac −1), comes back with the same
/// voxels through vellum's reader and the same geometry through SimpleITK's, within 1e-4 (NIfTI
/// stores the affine in 32-bit floats).
#[test]
fn nifti_output_keeps_voxels_and_geometry() {
    let dir = tempfile::tempdir().unwrap();
    let (c, s) = (30f64.to_radians().cos(), 30f64.to_radians().sin());
    let left = dir.path().join("left.nrrd");
    let header = format!(
        "NRRD0004\ntype: int16\ndimension: 3\nspace: left-posterior-superior\nsizes: 4 3 2\n\
         space directions: ({},{},0) ({},{},0) (0,0,-2.5)\nspace origin: (-12.5,40.25,7)\n\
         endian: little\nencoding: raw\n\n",
        0.5 * c,
        0.5 * s,
        -0.75 * s,
        0.75 * c
    );
    let mut bytes = header.into_bytes();
    bytes.extend((0..24i16).flat_map(|v| (v * 100 - 1000).to_le_bytes()));
    std::fs::write(&left, &bytes).unwrap();
    let mut inputs = vec![left];
    inputs.extend(format_files().unwrap_or_default());
    let mut pairs = Vec::new();
    for (i, input) in inputs.iter().enumerate() {
        let ext = if i % 2 == 0 { "nii.gz" } else { "nii" };
        let out = dir.path().join(format!("out{i}.{ext}"));
        ok(&vellum(&[
            "convert",
            input.to_str().unwrap(),
            out.to_str().unwrap(),
        ]));
        let a = vellum::volume::io::load(input, None).unwrap();
        let b = vellum::volume::io::load(&out, None).unwrap();
        let name = input.display();
        assert_eq!(a.dims, b.dims, "{name}");
        assert_eq!(a.data, b.data, "{name}: voxels");
        assert_close(&format!("{name} spacing"), &a.spacing, &b.spacing, 1e-5);
        assert_eq!(a.geometry.space, b.geometry.space, "{name}");
        assert_close(
            &format!("{name} origin"),
            &a.geometry.origin,
            &b.geometry.origin,
            1e-3,
        );
        let flat = |g: &vellum::volume::geometry::Geometry| g.direction.concat();
        assert_close(
            &format!("{name} direction"),
            &flat(&a.geometry),
            &flat(&b.geometry),
            1e-5,
        );
        pairs.push((input.clone(), out));
    }
    let all: Vec<&Path> = pairs
        .iter()
        .flat_map(|(a, b)| [a.as_path(), b.as_path()])
        .collect();
    let Some(g) = sitk(&all) else {
        return;
    };
    for (input, out) in &pairs {
        let (x, y) = (&g[input.to_str().unwrap()], &g[out.to_str().unwrap()]);
        let name = input.display().to_string();
        for key in ["size", "spacing", "origin", "direction"] {
            assert_close(
                &format!("{name} {key} (SimpleITK)"),
                &floats(&y[key]),
                &floats(&x[key]),
                1e-3,
            );
        }
    }
}

/// Output extensions choose the volume format; anything else is refused before writing.
#[test]
fn volume_outputs_take_nrrd_or_nifti_only() {
    let dir = tempfile::tempdir().unwrap();
    for bad in ["x.img", "x.mhd", "x.png", "x.nii.zip"] {
        let out = dir.path().join(bad);
        common::fails_with(
            &vellum(&["convert", "phantom:shepp-logan:16", out.to_str().unwrap()]),
            "does not end in .nrrd or .nii or .nii.gz",
        );
        assert!(!out.exists(), "{bad} must not be written");
    }
}
