//! Outputs are all or nothing, and special paths are refused (part of the hardening issue):
//! - a command whose second output fails leaves no first output (and no temporary files);
//! - two outputs of one command with the same path are refused;
//! - an output path that exists and is not a regular file (a FIFO here), or is a symbolic link,
//!   is refused and left as it was;
//! - an output whose extension does not name its format is refused;
//! - an input that is a FIFO, or a detached NRRD whose data file is /dev/zero, is refused at once
//!   rather than read forever.

mod common;

use common::{fails_with, mkfifo, only, vellum};
use std::path::Path;
use std::process::Command;

#[test]
fn a_failing_output_leaves_no_other_output() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let s = |n: &str| d.join(n).to_string_lossy().into_owned();
    let out = vellum(&[
        "render",
        "phantom:nested:16",
        "--size",
        "16x16",
        "--out",
        &s("a.png"),
        "--exr",
        &s("missing/b.exr"),
    ]);
    fails_with(&out, "missing/b.exr");
    only(d, &[]);
    // An existing first output is left as it was.
    std::fs::write(d.join("a.png"), b"old").unwrap();
    fails_with(
        &vellum(&[
            "render",
            "phantom:nested:16",
            "--size",
            "16x16",
            "--out",
            &s("a.png"),
            "--exr",
            &s("missing/b.exr"),
        ]),
        "missing/b.exr",
    );
    assert_eq!(std::fs::read(d.join("a.png")).unwrap(), b"old");
    only(d, &["a.png"]);
    // The same command with a good path writes both.
    let ok = vellum(&[
        "render",
        "phantom:nested:16",
        "--size",
        "16x16",
        "--out",
        &s("a.png"),
        "--exr",
        &s("b.exr"),
    ]);
    assert!(
        ok.status.success(),
        "{}",
        String::from_utf8_lossy(&ok.stderr)
    );
    only(d, &["a.png", "b.exr"]);
}

/// Every pair of output flags of every command that has several, given one path (written two
/// ways, relative and absolute), is refused before any work and leaves nothing behind.
#[test]
fn two_outputs_with_one_path_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let base: &[(&[&str], &[&str])] = &[
        (&["importance", "phantom:nested:16"], &["--out", "--slices"]),
        (
            &["occlusion", "phantom:nested:16", "--radius", "2"],
            &["--out", "--spectrum", "--spectrum-data"],
        ),
        (
            &["occlusion-sensitivity", "phantom:nested:16", "--radii", "2"],
            &["--out", "--csv"],
        ),
        (
            &["render", "phantom:nested:16"],
            &["--out", "--exr", "--save-scene"],
        ),
        (
            &[
                "migrate",
                "phantom:nested:64",
                "--seed",
                "46,32,32",
                "--window",
                "0.7:0.8",
                "--label",
                "s",
            ],
            &["--out", "--features"],
        ),
    ];
    let mut pairs = 0;
    for (command, flags) in base {
        for (i, a) in flags.iter().enumerate() {
            for b in &flags[i + 1..] {
                // One spelling relative to the working directory, the other absolute.
                let out = Command::new(env!("CARGO_BIN_EXE_vellum"))
                    .args(*command)
                    .args([a, &"same.out", b])
                    .arg(d.join("same.out"))
                    .current_dir(d)
                    .env("VELLUM_VALIDATION", "1")
                    .output()
                    .unwrap();
                fails_with(&out, "is given for two outputs of one command");
                only(d, &[]);
                pairs += 1;
            }
        }
    }
    assert_eq!(pairs, 9);
}

#[test]
fn special_output_paths_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let fifo = dir.path().join("f.nrrd");
    mkfifo(&fifo);
    fails_with(
        &vellum(&["convert", "phantom:shepp-logan:8", fifo.to_str().unwrap()]),
        "is not a regular file",
    );
    assert!(std::fs::symlink_metadata(&fifo)
        .unwrap()
        .file_type()
        .is_fifo_like());
    let target = dir.path().join("t.nrrd");
    std::fs::write(&target, b"keep").unwrap();
    let link = dir.path().join("l.nrrd");
    std::os::unix::fs::symlink(&target, &link).unwrap();
    fails_with(
        &vellum(&["convert", "phantom:shepp-logan:8", link.to_str().unwrap()]),
        "symbolic link",
    );
    assert_eq!(std::fs::read(&target).unwrap(), b"keep");
    fails_with(
        &vellum(&["convert", "phantom:shepp-logan:8", "/dev/null"]),
        "does not end in .nrrd",
    );
    let png = dir.path().join("x.jpg");
    fails_with(
        &vellum(&[
            "render",
            "phantom:nested:8",
            "--size",
            "8x8",
            "--out",
            png.to_str().unwrap(),
        ]),
        "does not end in .png",
    );
    only(dir.path(), &["f.nrrd", "t.nrrd", "l.nrrd"]);
}

trait FifoLike {
    fn is_fifo_like(&self) -> bool;
}

impl FifoLike for std::fs::FileType {
    fn is_fifo_like(&self) -> bool {
        use std::os::unix::fs::FileTypeExt;
        self.is_fifo()
    }
}

/// A FIFO behind every reader (each volume format by name, raw input, a DICOM folder, each JSON
/// file), and /dev/zero behind every reader that names a second file, is refused at once.
#[test]
fn endless_inputs_are_refused_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let png = d.join("x.png").to_string_lossy().into_owned();
    let path = |n: &str| d.join(n).to_string_lossy().into_owned();
    for name in [
        "in.nrrd",
        "in.nhdr",
        "in.nii",
        "in.nii.gz",
        "in.mhd",
        "in.mha",
        "in.raw",
        "in",
    ] {
        mkfifo(&d.join(name));
        fails_with(&vellum(&["info", &path(name)]), "not a regular file");
    }
    fails_with(
        &vellum(&[
            "info",
            &path("in.raw"),
            "--raw-dims",
            "4,4,4",
            "--raw-type",
            "u8",
        ]),
        "not a regular file",
    );
    std::fs::create_dir(d.join("series")).unwrap();
    mkfifo(&d.join("series/slice.dcm"));
    fails_with(&vellum(&["info", &path("series")]), "holds no DICOM images");
    for json in ["tf.json", "otf.json", "map.features.json", "scene.json"] {
        mkfifo(&d.join(json));
    }
    for (flag, file) in [
        ("--tf", "tf.json"),
        ("--otf", "otf.json"),
        ("--features", "map.features.json"),
        ("--scene", "scene.json"),
    ] {
        let f = path(file);
        let mut args = vec!["render", "phantom:nested:16", flag, &f, "--out", &png];
        if flag == "--scene" {
            args.remove(1);
        }
        fails_with(&vellum(&args), "not a regular file");
    }
    fails_with(
        &vellum(&["features", &path("map.features.json")]),
        "not a regular file",
    );
    // /dev/zero as the data file of a detached header, and as a raw input.
    std::fs::write(
        d.join("zero.nhdr"),
        "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 4 4 4\nencoding: raw\ndata file: /dev/zero\n",
    )
    .unwrap();
    std::fs::write(
        d.join("zero.mhd"),
        "NDims = 3\nDimSize = 4 4 4\nElementType = MET_UCHAR\nElementDataFile = /dev/zero\n",
    )
    .unwrap();
    for name in ["zero.nhdr", "zero.mhd"] {
        fails_with(&vellum(&["info", &path(name)]), "/dev/zero");
    }
    fails_with(
        &vellum(&[
            "info",
            "/dev/zero",
            "--raw-dims",
            "4,4,4",
            "--raw-type",
            "u8",
        ]),
        "not a regular file",
    );
    fails_with(
        &vellum(&["render", "--scene", "/dev/zero", "--out", &png]),
        "not a regular file",
    );
}

#[test]
fn numeric_parameters_are_checked_where_they_are_parsed() {
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("x.png").to_string_lossy().into_owned();
    // Stride 0 in every command that takes a stride (occlusion-sensitivity documents 0 as "pick
    // one").
    for args in [
        vec![
            "occlusion",
            "phantom:nested:16",
            "--radius",
            "2",
            "--stride",
            "0",
        ],
        vec![
            "occlusion-select",
            "phantom:nested:16",
            "--interval",
            "0.1:0.5",
            "--radius",
            "2",
            "--stride",
            "0",
        ],
    ] {
        fails_with(&vellum(&args), "output stride 0 is invalid");
    }
    fails_with(
        &vellum(&[
            "occlusion-sensitivity",
            "phantom:nested:16",
            "--radii",
            "2",
            "--bands",
            "100000000",
            "--out",
            &png,
        ]),
        "expected 1..=1024",
    );
    fails_with(
        &vellum(&[
            "occlusion-sensitivity",
            "phantom:nested:16",
            "--radii",
            "1,5000",
            "--out",
            &png,
        ]),
        "occlusion radius 5000",
    );
    fails_with(
        &vellum(&[
            "importance",
            "phantom:shepp-logan:16",
            "--radius",
            "4294967295",
        ]),
        "radius 4294967295 is too large",
    );
    fails_with(
        &vellum(&[
            "render",
            "phantom:nested:16",
            "--slices",
            "0",
            "--out",
            &png,
        ]),
        "slices 0 is invalid",
    );
    fails_with(
        &vellum(&["render", "phantom:nested:16", "--iso", "7", "--out", &png]),
        "outside the data range",
    );
    fails_with(
        &vellum(&[
            "render",
            "phantom:nested:16",
            "--focus",
            "0.2:0.5",
            "--one-pass",
            "--out",
            &png,
        ]),
        "--one-pass draws a single level",
    );
    // Values that may be negative are taken as values, not flags; the rest get a sentence.
    fails_with(
        &vellum(&[
            "render",
            "phantom:nested:16",
            "--size",
            "-64x64",
            "--out",
            &png,
        ]),
        "whole pixels of 1 or more",
    );
    fails_with(
        &vellum(&[
            "render",
            "phantom:nested:16",
            "--focus",
            "-2000:-500",
            "--out",
            &png,
        ]),
        "the focus interval -2000:-500 lies outside the data range",
    );
    fails_with(
        &vellum(&["bench", "table1", "--cases", "bogus", "--no-scipy"]),
        "selects no case",
    );
    // The validation switch is read by every command that opens a device.
    let out = Command::new(env!("CARGO_BIN_EXE_vellum"))
        .args(["roundtrip", "phantom:nested:8"])
        .env("VELLUM_VALIDATION", "maybe")
        .output()
        .unwrap();
    fails_with(&out, "VELLUM_VALIDATION=\"maybe\"");
    let out = Command::new(env!("CARGO_BIN_EXE_vellum"))
        .args(["devices", "--json"])
        .env("VELLUM_DEVICE", "99")
        .output()
        .unwrap();
    assert!(
        !out.status.success(),
        "VELLUM_DEVICE=99 devices --json must fail"
    );
    assert!(String::from_utf8_lossy(&out.stderr).contains("selector \"99\""));
    only(dir.path(), &[]);
}

#[test]
fn messages_say_what_was_expected() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(
        d.join("neg.nrrd"),
        "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 16 -16 16\nencoding: raw\n\n",
    )
    .unwrap();
    fails_with(
        &vellum(&["info", d.join("neg.nrrd").to_str().unwrap()]),
        "expected 3 whole numbers of zero or more",
    );
    std::os::unix::fs::symlink(d.join("loop.nrrd"), d.join("loop.nrrd")).unwrap();
    fails_with(
        &vellum(&["info", d.join("loop.nrrd").to_str().unwrap()]),
        "symbolic link that leads nowhere",
    );
    let mut big =
        b"NRRD0004\ntype: double\ndimension: 3\nsizes: 2 1 1\nendian: little\nencoding: raw\n\n"
            .to_vec();
    big.extend(1e300f64.to_le_bytes());
    big.extend(1.0f64.to_le_bytes());
    std::fs::write(d.join("big.nrrd"), big).unwrap();
    fails_with(
        &vellum(&["info", d.join("big.nrrd").to_str().unwrap()]),
        "beyond ±3.4e38",
    );
    std::fs::write(
        d.join("otf.json"),
        r#"{"name": "x", "radius": 4, "mapping": "ramp", "transfer": "rainbow"}"#,
    )
    .unwrap();
    let png = d.join("x.png");
    fails_with(
        &vellum(&[
            "render",
            "phantom:nested:16",
            "--otf",
            d.join("otf.json").to_str().unwrap(),
            "--out",
            png.to_str().unwrap(),
        ]),
        "otf.json: \"transfer\"",
    );
    assert!(!png.exists());
}

#[test]
fn a_feature_map_for_another_volume_or_with_no_features_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let examples = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/features");
    let map = examples.join("nested_sphere.features.json");
    let png = d.join("x.png");
    fails_with(
        &vellum(&[
            "render",
            "phantom:nested:64",
            "--features",
            map.to_str().unwrap(),
            "--out",
            png.to_str().unwrap(),
        ]),
        "was made for nested_sphere.nrrd",
    );
    std::fs::write(
        d.join("empty.json"),
        r#"{"version": 1, "context_range": [0, 1], "nodes": []}"#,
    )
    .unwrap();
    fails_with(
        &vellum(&[
            "render",
            examples.join("nested_sphere.nrrd").to_str().unwrap(),
            "--features",
            d.join("empty.json").to_str().unwrap(),
            "--out",
            png.to_str().unwrap(),
        ]),
        "holds no features",
    );
    assert!(!png.exists());
}
