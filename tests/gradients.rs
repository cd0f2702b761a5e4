//! Gradients made at each sample (issue 39), on lavapipe with validation and synchronization
//! validation on. A volume whose intensity fits the GPU budget and whose stored gradients would
//! not is drawn in core with no gradient texture: the ray caster makes each shaded sample's Sobel
//! gradient from 26 intensity fetches (`shade.glsl`'s `sobel_at`, whose CPU reference
//! `reference::sobel::sobel_at` is the trilinear interpolation of the stored operator's
//! gradients).
//! - Its frames are the frames with stored gradients within a mean of 0.05/255 (observed
//!   0.0002-0.008/255; single pixels up to 47/255 where a gradient is near zero and the stored
//!   half floats round it), one pass and two levels, with an image-space style, on the
//!   phantoms, the CT head and the chest, with the same depths.
//! - The session picks it by the budget: stored gradients when they fit, made at each sample
//!   when only the intensity does, the brick cache below that; `render --json` names it, runs no
//!   `sobel_normals` pass for it, and a slicer view of it is made a ray-cast one with a sentence.
//!   A scene that makes another whole-volume texture (here a style's object-space lines) is held
//!   to stored gradients.

mod common;

use common::Gpu;
use vellum::classify::transfer::TransferFunction;
use vellum::classify::{Classification, Focus};
use vellum::passes::normals::{GradientSource, Normals};
use vellum::render::frame::Renderer;
use vellum::render::scene::{GpuScene, Scale};
use vellum::volume::{phantom, Volume};

use common::diff8;

/// `v` resampled to 128 voxels along its longest axis.
fn at_128(v: Volume) -> Volume {
    let scale = 128.0 / *v.dims.iter().max().unwrap() as f64;
    let dims = v.dims.map(|n| ((n as f64 * scale).round() as usize).max(1));
    vellum::volume::resample::trilinear(&v, dims).unwrap()
}

#[test]
fn frames_with_gradients_made_at_each_sample_are_the_frames_with_stored_ones() {
    let gpu = Gpu::new();
    let normals = Normals::new(&gpu.ctx).unwrap();
    let mut renderer = Renderer::new(&gpu.ctx).unwrap();
    let mut cases = vec![
        (
            "shepp-logan",
            phantom::shepp_logan(128),
            "grey",
            0.9,
            "30,20,2.5",
        ),
        ("nested", phantom::nested(128), "grey", 0.6, "0,30,2.5"),
    ];
    if let Some(v) = common::real_volume("cthead_stanford") {
        cases.push(("cthead", at_128(v), "ct-skin-bone", 1300.0, "0,0,2.4"));
    }
    let chest = concat!(env!("CARGO_MANIFEST_DIR"), "/data/ct_chest/ct_chest.nhdr");
    let chest = at_128(vellum::input::load(chest, None).unwrap());
    cases.push(("chest", chest, "ct-skin-bone", 150.0, "30,10,2.4"));
    for (name, v, tf, iso, camera) in cases {
        let c = Classification::Transfer(TransferFunction::preset(tf).unwrap());
        let prepare = |source| {
            let input = (&v, Scale::default(), source);
            GpuScene::prepare_with(&normals, input, &c, Focus::Iso(iso), &Default::default())
                .unwrap()
        };
        let (mut stored, mut at_sample) = (
            prepare(GradientSource::Stored),
            prepare(GradientSource::AtSample),
        );
        assert!(stored.volume.gradient.image().is_some());
        assert!(at_sample.volume.gradient.image().is_none());
        for (one_pass, style) in [(true, None), (false, None), (false, Some("canny"))] {
            let view = common::ray_view(camera, one_pass, style, None);
            let want = renderer
                .render_frame(&stored.volume, &mut stored.classify, &view, true)
                .unwrap();
            let got = renderer
                .render_frame(&at_sample.volume, &mut at_sample.classify, &view, true)
                .unwrap();
            let (mean, max) = diff8(&want, &got);
            println!(
                "{name} one pass {one_pass} style {style:?}: mean {mean:.4}/255, max {max}/255"
            );
            assert!(mean <= 0.05, "{name}: mean {mean}/255");
            let lit = got.composite.iter().filter(|p| p[3] > 0.5).count();
            assert!(lit > 1000, "{name}: only {lit} pixels drawn");
            // Nothing but the shading differs: the same samples reach the same depths.
            if let (Some(a), Some(b)) = (want.layers, got.layers) {
                assert_eq!(a.focus_depth, b.focus_depth, "{name} depth");
            }
        }
    }
}

/// `vellum render` of a 96³ phantom through `budget` MiB: its report and what it said.
fn render(dir: &std::path::Path, budget: &str, renderer: &[&str]) -> (serde_json::Value, String) {
    let out = dir.join(format!("b{budget}.png"));
    let args = [
        &[
            "render",
            "phantom:shepp-logan:96",
            "--iso",
            "0.9",
            "--tf",
            "grey",
            "--size",
            "64x64",
            "--gpu-budget",
            budget,
            "--json",
            "--out",
            out.to_str().unwrap(),
        ][..],
        renderer,
    ]
    .concat();
    let o = common::vellum(&args);
    let said = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(o.status.success(), "{said}");
    assert!(out.exists());
    (serde_json::from_slice(&o.stdout).unwrap(), said)
}

#[test]
fn the_session_makes_gradients_at_each_sample_where_only_the_intensity_fits() {
    let dir = tempfile::tempdir().unwrap();
    let raycast = ["--renderer", "raycast"];
    // 96³: intensity 1.7 MiB, with stored gradients 8.4 MiB.
    let (r, said) = render(dir.path(), "16", &raycast);
    assert_eq!(r["gradients"], "stored", "{said}");
    assert!(r["passes"]["sobel_normals"].is_number());
    let (r, said) = render(dir.path(), "4", &raycast);
    assert_eq!(r["gradients"], "at_sample", "{said}");
    assert!(r["bricks"].is_null(), "in core");
    assert!(
        r["passes"]["sobel_normals"].is_null(),
        "no gradients are stored"
    );
    assert!(r["peak_device_mib"].as_f64().unwrap() < 16.0, "{r}");
    let (r, said) = render(dir.path(), "1", &raycast);
    assert_eq!(r["gradients"], "pool", "{said}");
    assert!(r["bricks"]["complete"].as_bool().unwrap());
    // A style with object-space lines makes another whole-volume texture, which the rule does not
    // count: the scene is held to stored gradients, so 4 MiB sends it to the brick cache, which
    // refuses the lines in one sentence.
    let out = dir.path().join("lines.png");
    let o = common::vellum(&[
        "render",
        "phantom:shepp-logan:96",
        "--iso",
        "0.9",
        "--style",
        "11",
        "--gpu-budget",
        "4",
        "--out",
        out.to_str().unwrap(),
    ]);
    common::fails_with(&o, "object-space lines");
    assert!(!out.exists());
    // The slicer is asked for: the ray caster draws it, and says why.
    let (r, said) = render(dir.path(), "4", &[]);
    assert_eq!(r["gradients"], "at_sample");
    assert!(
        said.contains("gradients do not fit the GPU budget (4 MiB)")
            && said.contains("making them at each sample"),
        "{said}"
    );
}
