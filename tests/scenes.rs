//! Scene files through the `vellum` binary (validation on): every example scene renders, a saved
//! scene renders the same PNG as the command line that saved it, flags override the file, and
//! each kind of bad scene file ends with one sentence that names the key or value, and no output.

mod common;

use common::vellum;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn ok(out: &Output) {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!stderr.contains("validation layer"), "{stderr}");
}

fn examples() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("examples")
}

/// The example scenes (files with a "version" key; the others are transfer functions).
fn example_scenes() -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(examples())
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| {
            p.extension().is_some_and(|e| e == "json")
                && std::fs::read_to_string(p).unwrap().contains("\"version\"")
        })
        .collect();
    v.sort();
    v
}

#[test]
fn every_example_scene_renders() {
    let scenes = example_scenes();
    assert!(scenes.len() >= 6, "{scenes:?}");
    let needs_data = |p: &Path| std::fs::read_to_string(p).unwrap().contains("shared/data");
    let have_data = common::shared_data().is_some();
    let dir = tempfile::tempdir().unwrap();
    for scene in scenes {
        if needs_data(&scene) && !have_data {
            continue;
        }
        let out = dir.path().join("x.png");
        ok(&vellum(&[
            "render",
            "--scene",
            scene.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ]));
        let img = image::open(&out).unwrap().to_rgb8();
        let lit = img.pixels().filter(|p| p.0.iter().any(|&c| c > 40)).count();
        assert!(lit > 200, "{}: only {lit} lit pixels", scene.display());
        std::fs::remove_file(&out).unwrap();
    }
}

#[test]
fn a_saved_scene_renders_the_same_png() {
    let dir = tempfile::tempdir().unwrap();
    let p = |n: &str| dir.path().join(n).to_string_lossy().into_owned();
    ok(&vellum(&[
        "render",
        "phantom:nested:40",
        "--iso",
        "0.6",
        "--camera",
        "-30,35,2.7",
        "--size",
        "64x48",
        "--background",
        "0.2,0.1,0",
        "--out",
        &p("a.png"),
        "--save-scene",
        &p("scene.json"),
    ]));
    // From another folder: the saved paths do not depend on the working directory.
    let out = Command::new(env!("CARGO_BIN_EXE_vellum"))
        .args(["render", "--scene", &p("scene.json"), "--out", &p("b.png")])
        .current_dir(std::env::temp_dir())
        .env("VELLUM_VALIDATION", "1")
        .output()
        .unwrap();
    ok(&out);
    assert_eq!(
        std::fs::read(p("a.png")).unwrap(),
        std::fs::read(p("b.png")).unwrap()
    );
    // --save-scene alone writes the scene and renders nothing.
    ok(&vellum(&[
        "render",
        "--scene",
        &p("scene.json"),
        "--size",
        "32x32",
        "--save-scene",
        &p("small.json"),
    ]));
    let small = std::fs::read_to_string(p("small.json")).unwrap();
    let v: serde_json::Value = serde_json::from_str(&small).unwrap();
    assert_eq!(
        v["size"],
        serde_json::json!([32, 32]),
        "the flag overrides the file"
    );
    assert_eq!(
        v["focus"],
        serde_json::json!({"iso": 0.6}),
        "the file's other values stay"
    );
    // A flag given with --scene overrides the file in the render too.
    ok(&vellum(&[
        "render",
        "--scene",
        &p("scene.json"),
        "--size",
        "24x20",
        "--out",
        &p("c.png"),
    ]));
    let c = image::open(p("c.png")).unwrap();
    assert_eq!((c.width(), c.height()), (24, 20));
}

/// Writes `json` as a scene and renders it: it must fail with one sentence containing each of
/// `phrases`, and write nothing.
fn bad_scene(json: &str, phrases: &[&str]) {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("bad.json");
    std::fs::write(&scene, json).unwrap();
    let out_png = dir.path().join("out.png");
    let out = vellum(&[
        "render",
        "--scene",
        scene.to_str().unwrap(),
        "--out",
        out_png.to_str().unwrap(),
    ]);
    common::fails_with_all(&out, phrases);
    assert!(!out_png.exists(), "{json}: wrote an output");
}

#[test]
fn bad_scene_files_get_one_sentence() {
    let input = r#""input": {"path": "phantom:nested:16"}"#;
    bad_scene(
        &format!(r#"{{"version": 1, {input}, "colour": [1, 0, 0]}}"#),
        &["unknown field `colour`", "expected one of"],
    );
    bad_scene(
        &format!(r#"{{"version": 1, {input}, "size": "big"}}"#),
        &["invalid type", "big", "bad.json"],
    );
    bad_scene(r#"{"version": 1}"#, &["missing field `input`"]);
    bad_scene(
        &format!(r#"{{"version": 1, {input}, "classification": {{"transfer": "rainbow"}}}}"#),
        &["bad.json: classification", "rainbow", "preset"],
    );
    bad_scene(
        &format!(r#"{{"version": 1, {input}, "classification": {{"curvature": "x"}}}}"#),
        &["unknown variant `curvature`"],
    );
    bad_scene(
        r#"{"version": 1, "input": {"path": "no/such/volume.nrrd"}}"#,
        &["bad.json: input", "does not exist"],
    );
    bad_scene(
        &format!(
            r#"{{"version": 1, {input}, "classification": {{"occlusion": "missing_otf.json"}}}}"#
        ),
        &["missing_otf.json"],
    );
    bad_scene(
        &format!(r#"{{"version": 2, {input}}}"#),
        &["version 2", "\"version\": 1"],
    );
    bad_scene(
        &format!(r#"{{"version": 1, {input}, "camera": {{"elevation": 120}}}}"#),
        &["elevation 120"],
    );
    bad_scene(
        &format!(r#"{{"version": 1, {input}, "style": {{"style": 7, "glow": 1}}}}"#),
        &["unknown field `glow`"],
    );
    bad_scene(
        &format!(
            r#"{{"version": 1, {input}, "style": {{"style": 7, "params": {{"line_stride": 0}}}}}}"#
        ),
        &["bad.json: style", "line stride 0 is invalid"],
    );
    bad_scene(
        &format!(r#"{{"version": 1, {input}, "style": {{"style": "glow"}}}}"#),
        &["style \"glow\" is unknown", "15 none"],
    );
    bad_scene(
        &format!(
            r#"{{"version": 1, {input}, "style": {{"style": 2, "params": {{"dog_sigma": -1}}}}}}"#
        ),
        &["DoG σ -1"],
    );
    bad_scene(
        &format!(r#"{{"version": 1, {input}, "style": {{"style": 1}}}}"#),
        &["works on the focus layer"],
    );
    bad_scene(
        &format!(r#"{{"version": 1, {input}, "modulation": {{"gamma": 5}}}}"#),
        &["unknown field `gamma`"],
    );
    bad_scene(
        &format!(
            r#"{{"version": 1, {input}, "modulation": {{"opacity": {{"t_low": 0.8, "t_high": 0.2, "k_low": 1, "k_high": 1}}}}}}"#
        ),
        &["bad.json", "t_l <= t_h"],
    );
    bad_scene("{not json", &["bad.json", "key must be a string"]);
}

/// Runs `render phantom:nested:24 <args> --out DIR/x.png`: one sentence containing `phrase`, no file.
fn bad_flags(args: &[&str], phrase: &str) {
    let dir = tempfile::tempdir().unwrap();
    let out_png = dir.path().join("x.png");
    let mut all = vec!["render", "phantom:nested:24", "--size", "16x16"];
    all.extend_from_slice(args);
    all.extend_from_slice(&["--out", out_png.to_str().unwrap()]);
    common::fails_with(&vellum(&all), phrase);
    assert!(!out_png.exists());
}

#[test]
fn bad_modulation_flags_get_one_sentence() {
    bad_flags(&["--opacity-mod", "0.8,0.2,1,1"], "t_l <= t_h");
    bad_flags(&["--opacity-mod", "0.1,0.2,1"], "expected 4");
    bad_flags(
        &["--color-mod", "raw", "--gamma", "inf"],
        "not a finite number",
    );
    bad_flags(&["--color-mod", "raw"], "--color-mod needs --gamma");
    bad_flags(&["--gamma", "3"], "--gamma needs --color-mod");
    bad_flags(
        &["--color-mod", "log", "--gamma", "3"],
        "expected raw or abs",
    );
    bad_flags(&["--stipple", "0.1,-2"], "f = -2");
    bad_flags(&["--stipple", "1.5,2"], "outside [0, 1]");
    bad_flags(
        &["--stipple", "0.1,2", "--importance-radius", "0"],
        "importance radius",
    );
    bad_flags(
        &["--stipple", "0.1,2", "--importance-radius", "40"],
        "radius 40",
    );
    bad_flags(&["--seed", "4"], "--seed needs --stipple");
    bad_flags(&["--modulate", "focus"], "need an effect");
}

#[test]
fn bad_style_flags_get_one_sentence() {
    bad_flags(&["--iso", "0.4", "--style", "99"], "expected a number 1-15");
    bad_flags(
        &[
            "--iso",
            "0.4",
            "--style",
            "dog+silhouettes",
            "--line-angle",
            "95",
        ],
        "line angle 95 is invalid",
    );
    bad_flags(
        &["--iso", "0.4", "--style", "2", "--sigma", "-2"],
        "DoG σ -2",
    );
    bad_flags(
        &["--iso", "0.4", "--style", "13", "--kuwahara-radius", "-3"],
        "Kuwahara radius -3",
    );
    bad_flags(
        &["--iso", "0.4", "--style", "1", "--edge-threshold", "1.5"],
        "outside [0, 1]",
    );
    bad_flags(
        &["--iso", "0.4", "--style", "13", "--edge-threshold", "0.5"],
        "no effect",
    );
    bad_flags(&["--style", "3"], "works on the focus layer");
    bad_flags(
        &["--iso", "0.4", "--style", "3", "--one-pass"],
        "drop --one-pass",
    );
    bad_flags(&["--sigma", "2"], "need --style");
}

#[test]
fn bad_view_flags_get_one_sentence() {
    bad_flags(&["--view", "sideways"], "view \"sideways\" is unknown");
    bad_flags(&["--view", "left", "--camera", "0,0"], "not both");
    bad_flags(&["--camera", "0,120"], "elevation 120");
}

#[test]
fn the_same_stipple_seed_gives_the_same_png() {
    let dir = tempfile::tempdir().unwrap();
    let run = |name: &str, seed: &str| {
        let p = dir.path().join(name);
        ok(&vellum(&[
            "render",
            "phantom:shepp-logan:48",
            "--size",
            "64x64",
            "--importance-radius",
            "4",
            "--stipple",
            "0.1,10",
            "--seed",
            seed,
            "--out",
            p.to_str().unwrap(),
        ]));
        std::fs::read(p).unwrap()
    };
    let (a, b, c) = (run("a.png", "1"), run("b.png", "1"), run("c.png", "2"));
    assert_eq!(a, b);
    assert_ne!(a, c);
}

#[test]
fn the_styles_gallery_and_the_saliency_command() {
    let dir = tempfile::tempdir().unwrap();
    let p = |n: &str| dir.path().join(n).to_string_lossy().into_owned();
    let out = vellum(&[
        "styles",
        "phantom:nested:40",
        "--iso",
        "0.4",
        "--size",
        "48x48",
        "--out",
        &p("gallery.png"),
        "--out-dir",
        &p("each"),
        "--exr",
        "--saliency",
        "--json",
    ]);
    ok(&out);
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let styles = v["styles"].as_array().unwrap();
    assert_eq!(styles.len(), 15);
    let rendered: Vec<u64> = styles
        .iter()
        .filter(|s| s["rendered"] == true)
        .map(|s| s["number"].as_u64().unwrap())
        .collect();
    assert_eq!(
        rendered,
        (1..=15).collect::<Vec<u64>>(),
        "every style renders"
    );
    for s in styles.iter().filter(|s| s["rendered"] == true) {
        let share = s["focus_share"].as_f64().unwrap();
        assert!((0.0..=1.0).contains(&share), "{s}");
    }
    let g = image::open(p("gallery.png")).unwrap();
    assert!(g.width() > 5 * 48 && g.height() > 3 * 48);
    for f in [
        "style02_dog.png",
        "style02_dog.exr",
        "style13_kuwahara.png",
        "style15_none.exr",
    ] {
        assert!(dir.path().join("each").join(f).exists(), "{f}");
    }
    assert!(dir.path().join("each/style07_dog_silhouettes.png").exists());
    let sal = vellum(&[
        "saliency",
        &p("each/style02_dog.png"),
        "--mask",
        &p("each/style02_dog.png"),
        "--out",
        &p("map.png"),
        "--json",
    ]);
    ok(&sal);
    let s: serde_json::Value = serde_json::from_slice(&sal.stdout).unwrap();
    assert!(s["mean_inside"].as_f64().unwrap() > s["mean_outside"].as_f64().unwrap());
    assert!(image::open(p("map.png")).is_ok());
}
