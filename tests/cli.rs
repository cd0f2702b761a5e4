//! The `vellum` binary end to end: each kind of bad input ends with a non-zero exit and one clear
//! sentence (no panic, no backtrace, no partial output), and the main commands produce their files.

mod common;

use std::path::Path;
use std::process::{Command, Output};

fn vellum(args: &[&str], env: &[(&str, &str)]) -> Output {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_vellum"));
    cmd.args(args)
        .env("VELLUM_VALIDATION", "1")
        .env_remove("RUST_BACKTRACE");
    for (k, v) in env {
        cmd.env(k, v);
    }
    cmd.output().expect("run vellum")
}

/// Asserts failure with exactly one line on stderr, starting "error:" and containing `phrase`.
fn fails_with(out: &Output, phrase: &str) {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success(),
        "expected failure, got success; stderr: {stderr}"
    );
    assert_ne!(out.status.code(), Some(101), "panicked: {stderr}");
    let lines: Vec<&str> = stderr.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "expected one sentence, got: {stderr}");
    assert!(lines[0].starts_with("error: "), "{stderr}");
    assert!(
        lines[0].contains(phrase),
        "expected '{phrase}' in: {stderr}"
    );
    assert!(
        !stderr.contains("panicked") && !stderr.contains("backtrace"),
        "{stderr}"
    );
}

fn write(path: &Path, bytes: &[u8]) {
    std::fs::write(path, bytes).unwrap();
}

fn gzip(bytes: &[u8]) -> Vec<u8> {
    use std::io::Write;
    let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    e.write_all(bytes).unwrap();
    e.finish().unwrap()
}

#[test]
fn missing_file() {
    fails_with(
        &vellum(&["info", "/no/such/volume.nrrd"], &[]),
        "does not exist",
    );
}

#[test]
fn unknown_format() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("notes.xyz");
    write(&p, b"hello, this is not a volume");
    fails_with(
        &vellum(&["info", p.to_str().unwrap()], &[]),
        "unknown format",
    );
}

#[test]
fn header_sizes_disagree_with_data() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("short.nrrd");
    let mut bytes =
        b"NRRD0004\ntype: uint8\ndimension: 3\nsizes: 4 4 4\nencoding: raw\n\n".to_vec();
    bytes.extend_from_slice(&[7u8; 60]);
    write(&p, &bytes);
    fails_with(&vellum(&["info", p.to_str().unwrap()], &[]), "64");
}

#[test]
fn truncated_gzip() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("cut.nrrd");
    let mut bytes = b"NRRD0004\ntype: uint16\ndimension: 3\nsizes: 32 32 32\nendian: little\nencoding: gzip\n\n".to_vec();
    let z = gzip(&vec![3u8; 32 * 32 * 32 * 2]);
    bytes.extend_from_slice(&z[..z.len() / 2]);
    write(&p, &bytes);
    let out_file = dir.path().join("converted.nrrd");
    fails_with(
        &vellum(
            &["convert", p.to_str().unwrap(), out_file.to_str().unwrap()],
            &[],
        ),
        "truncated",
    );
    assert!(!out_file.exists(), "no partial output may be left behind");
    assert_eq!(
        std::fs::read_dir(dir.path()).unwrap().count(),
        1,
        "no temporary files either"
    );
}

#[test]
fn unsupported_type() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("block.nrrd");
    write(&p, b"NRRD0004\ntype: block\nblock size: 4\ndimension: 3\nsizes: 2 2 2\nencoding: raw\n\n01234567012345670123456701234567");
    fails_with(
        &vellum(&["info", p.to_str().unwrap()], &[]),
        "not supported",
    );
}

#[test]
fn zero_and_absurd_dims() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("v.raw");
    write(&p, &[0u8; 8]);
    fails_with(
        &vellum(
            &[
                "info",
                p.to_str().unwrap(),
                "--raw-dims",
                "0,2,4",
                "--raw-type",
                "u8",
            ],
            &[],
        ),
        "zero",
    );
    let h = dir.path().join("huge.nrrd");
    write(&h, b"NRRD0004\ntype: float\ndimension: 3\nsizes: 100000 100000 100000\nencoding: raw\n\n\0\0\0\0");
    fails_with(&vellum(&["info", h.to_str().unwrap()], &[]), "voxels");
}

#[test]
fn dims_beyond_the_device_limit() {
    // lavapipe's maxImageDimension3D is 4096: a 5000-voxel row fits in memory but not in a 3D image.
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("long.raw");
    write(&p, &vec![1u8; 5000 * 2]);
    let out = vellum(
        &[
            "roundtrip",
            p.to_str().unwrap(),
            "--raw-dims",
            "5000,2,1",
            "--raw-type",
            "u8",
        ],
        &[],
    );
    fails_with(&out, "at most 4096");
}

#[test]
fn nan_voxels_are_counted() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("nan.raw");
    let mut v = vec![1.0f32; 27];
    v[3] = f32::NAN;
    v[9] = f32::INFINITY;
    v[20] = f32::NAN;
    write(&p, bytemuck::cast_slice(&v));
    fails_with(
        &vellum(
            &[
                "info",
                p.to_str().unwrap(),
                "--raw-dims",
                "3,3,3",
                "--raw-type",
                "f32",
            ],
            &[],
        ),
        "3 NaN or infinite",
    );
}

#[test]
fn raw_with_wrong_size_and_bad_flags() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("v.raw");
    write(&p, &[0u8; 10]);
    fails_with(
        &vellum(
            &[
                "info",
                p.to_str().unwrap(),
                "--raw-dims",
                "2,2,2",
                "--raw-type",
                "u16",
            ],
            &[],
        ),
        "16",
    );
    fails_with(
        &vellum(
            &[
                "info",
                p.to_str().unwrap(),
                "--raw-dims",
                "2,2",
                "--raw-type",
                "u8",
            ],
            &[],
        ),
        "three whole numbers",
    );
    fails_with(
        &vellum(
            &[
                "info",
                p.to_str().unwrap(),
                "--raw-dims",
                "2,5,1",
                "--raw-type",
                "u64",
            ],
            &[],
        ),
        "unknown voxel type",
    );
}

#[test]
fn no_vulkan_device() {
    let out = vellum(
        &["roundtrip", "phantom:shepp-logan:8"],
        &[
            ("VK_DRIVER_FILES", "/nonexistent/icd.json"),
            ("VK_ICD_FILENAMES", "/nonexistent/icd.json"),
        ],
    );
    fails_with(&out, "no usable Vulkan device");
}

#[test]
fn devices_names_lavapipe() {
    let out = vellum(&["devices"], &[]);
    assert!(out.status.success());
    let s = String::from_utf8_lossy(&out.stdout);
    assert!(
        s.lines().any(|l| l.starts_with('*')),
        "a device is marked as chosen: {s}"
    );
    assert!(s.contains("llvmpipe"), "lavapipe is listed: {s}");
}

#[test]
fn info_prints_figures_for_phantom_nifti_and_dicom() {
    let out = vellum(&["info", "phantom:shepp-logan:32", "--json"], &[]);
    assert!(out.status.success());
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(j["dims"], serde_json::json!([32, 32, 32]));
    assert_eq!(j["histogram"].as_array().unwrap().len(), 16);
    let Some(data) = common::shared_data() else {
        return;
    };
    let nii = data.join("formats/nifti/stroke_t1.nii.gz");
    let j: serde_json::Value =
        serde_json::from_slice(&vellum(&["info", nii.to_str().unwrap(), "--json"], &[]).stdout)
            .unwrap();
    assert_eq!(j["dims"], serde_json::json!([124, 160, 140]));
    assert_eq!(j["max"], serde_json::json!(252.0));
    let dcm = data.join("formats/dicom/vs_seg001_t1");
    let j: serde_json::Value =
        serde_json::from_slice(&vellum(&["info", dcm.to_str().unwrap(), "--json"], &[]).stdout)
            .unwrap();
    assert_eq!(j["dims"], serde_json::json!([512, 512, 120]));
    assert!(j["mean"].as_f64().unwrap() > 0.0);
}

#[test]
fn importance_writes_nrrd_png_and_json() {
    let dir = tempfile::tempdir().unwrap();
    let dd = dir.path().join("dd.nrrd");
    let png = dir.path().join("dd.png");
    let out = vellum(
        &[
            "importance",
            "phantom:shepp-logan:40",
            "--radius",
            "3",
            "--out",
            dd.to_str().unwrap(),
            "--slices",
            png.to_str().unwrap(),
            "--json",
        ],
        &[],
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        out.stderr.is_empty(),
        "validation or other warnings: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    for pass in ["gauss_x", "gauss_y", "gauss_z", "subtract"] {
        assert!(j["passes"][pass].as_f64().unwrap() >= 0.0);
    }
    assert!(j["total_ms"].as_f64().unwrap() > 0.0);
    let v = vellum::volume::io::load(&dd, None).unwrap();
    assert_eq!(v.dims, [40, 40, 40]);
    assert_eq!(v.voxel_type(), vellum::volume::VoxelType::F32);
    let img = image::open(&png).unwrap();
    assert!(img.width() > 120 && img.height() > 40);
}
