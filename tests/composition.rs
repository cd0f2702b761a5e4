//! A feature map composed with an occlusion transfer function (issue 29, `classify::compose`),
//! checked against the separate renders where they must agree, on lavapipe with validation:
//! - where no ray meets a feature, the composed render is the occlusion TF's render of the
//!   original volume (the occlusion volume is the original data's, the context the OTF's);
//! - where the occlusion TF shows nothing, the composed render is the features alone, in their
//!   colour;
//! - and both are present in one picture.
//!
//! The data: `examples/features/nested_sphere.nrrd`, the 64³ nested phantom with its inner sphere
//! migrated (`vellum migrate phantom:nested:64 ...`), its map, and `examples/nested_otf.json`.

mod common;

use common::Gpu;
use std::path::{Path, PathBuf};
use vellum::classify::modulation::Modulation;
use vellum::classify::otf::OcclusionTf;
use vellum::classify::{Classification, Focus};
use vellum::render::camera::Camera;
use vellum::render::frame::Renderer;
use vellum::render::scene::GpuScene;
use vellum::render::view::{Lighting, View};
use vellum::volume::feature::FeatureMap;
use vellum::volume::{phantom, Volume};

fn example(p: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("examples")
        .join(p)
}

fn view() -> View {
    View {
        camera: Camera {
            azimuth_deg: 0.0,
            elevation_deg: 20.0,
            distance: 2.2,
            ..Camera::default()
        },
        size: [96, 96],
        slices: None,
        one_pass: true,
        lighting: Lighting::default(),
        style: None,
        fit: false,
        raycast: None,
    }
}

/// The premultiplied RGBA frame of `v` classified by `c`.
fn render(gpu: &Gpu, v: &Volume, c: &Classification) -> Vec<[f32; 4]> {
    let mut scene = GpuScene::prepare(&gpu.ctx, v, c, Focus::None, &Modulation::default()).unwrap();
    let mut renderer = Renderer::new(&gpu.ctx).unwrap();
    renderer
        .render_frame(&scene.volume, &mut scene.classify, &view(), true)
        .unwrap()
        .composite
}

/// An occlusion TF that shows nothing: one transparent region.
fn invisible(otf: &OcclusionTf) -> OcclusionTf {
    let mut none = otf.clone();
    for r in &mut none.regions {
        r.rgba[3] = 0.0;
    }
    none
}

#[test]
fn composed_render_agrees_with_the_separate_ones() {
    let gpu = Gpu::new();
    let features = vellum::input::load(
        example("features/nested_sphere.nrrd").to_str().unwrap(),
        None,
    )
    .unwrap();
    let original = phantom::nested(64);
    assert_eq!(
        features.dims, original.dims,
        "the example was migrated from phantom:nested:64"
    );
    let map = FeatureMap::load(&example("features/nested_sphere.features.json")).unwrap();
    let otf = OcclusionTf::load(&example("nested_otf.json")).unwrap();
    let colour = map.features()[0].1.color;

    let composed = render(
        &gpu,
        &features,
        &Classification::Composed(map.clone(), otf.clone()),
    );
    let alone_otf = render(&gpu, &original, &Classification::Occlusion(otf.clone()));
    let alone_features = render(
        &gpu,
        &features,
        &Classification::Composed(map.clone(), invisible(&otf)),
    );

    // Where the features alone show nothing (with a margin of one pixel for the sphere's edge),
    // the composed render is the occlusion TF's render of the original volume.
    let n = 96usize;
    let near_feature = |i: usize| {
        let (x, y) = ((i % n) as i64, (i / n) as i64);
        (-1..=1).any(|dy| {
            (-1..=1).any(|dx| {
                let (xx, yy) = (x + dx, y + dy);
                (0..n as i64).contains(&xx)
                    && (0..n as i64).contains(&yy)
                    && alone_features[(yy * n as i64 + xx) as usize][3] > 1e-3
            })
        })
    };
    let (mut compared, mut worst) = (0usize, 0f32);
    for i in 0..n * n {
        if near_feature(i) {
            continue;
        }
        compared += 1;
        for k in 0..4 {
            worst = worst.max((composed[i][k] - alone_otf[i][k]).abs());
        }
    }
    eprintln!("composed vs occlusion TF alone: largest difference {worst} over {compared} pixels");
    assert!(
        compared > n * n / 2,
        "most of the frame misses the feature ({compared})"
    );
    // Tolerance 0.02: the composed occlusion volume's visibility is a 256-bin table of the ramp.
    assert!(
        worst < 0.02,
        "composed vs occlusion TF alone, away from the feature: {worst}"
    );
    assert!(
        alone_otf.iter().filter(|p| p[3] > 0.1).count() > 100,
        "the occlusion TF shows the context"
    );

    // The features alone are in their colour. Diffuse shading scales it and the specular
    // highlight adds white, so the hue is compared: (g − b) / (r − b), which neither changes.
    let hue = |p: &[f32]| (p[1] - p[2]) / (p[0] - p[2]).max(1e-6);
    let in_colour =
        |p: &[f32; 4]| p[3] > 0.5 && p[0] > p[2] + 0.05 && (hue(p) - hue(&colour)).abs() < 0.05;
    let covered = alone_features.iter().filter(|p| p[3] > 0.5).count();
    assert!(covered > 50, "the feature covers pixels ({covered})");
    for p in alone_features.iter().filter(|p| p[3] > 0.5) {
        assert!(
            in_colour(p),
            "feature pixel {p:?} is not in the feature's colour {colour:?}"
        );
    }

    // Both in one picture: the composed render holds the feature's colour inside the context.
    let shown = composed.iter().filter(|p| in_colour(p)).count();
    assert!(
        shown > 10,
        "the feature shows in the composed render ({shown})"
    );
}

#[test]
fn scene_files_and_flags_compose() {
    // The scene file form, and its paths resolved against the file's folder.
    let scene = vellum::render::scene::Scene::load(&example("chest_composed.json")).unwrap();
    match scene.classification().unwrap() {
        Classification::Composed(map, otf) => {
            assert_eq!(map.features()[0].1.label, "heart");
            assert_eq!(otf.radius, 12);
        }
        other => panic!("expected a composed classification, not {other:?}"),
    }
    // On the command line, --features with --otf compose: the occlusion pass runs.
    let out = common::vellum(&[
        "render",
        example("features/nested_sphere.nrrd").to_str().unwrap(),
        "--features",
        example("features/nested_sphere.features.json")
            .to_str()
            .unwrap(),
        "--otf",
        example("nested_otf.json").to_str().unwrap(),
        "--size",
        "64x64",
        "--json",
        "--out",
        std::env::temp_dir()
            .join(format!("vellum-composed-{}.png", std::process::id()))
            .to_str()
            .unwrap(),
    ]);
    let json = common::ok_json(&out);
    assert!(json["passes"]["occlusion"].is_number(), "{json}");
}

/// The composed chest scene (`examples/chest_composed.json`, the showcase's first picture) shows
/// all four techniques: the migrated heart's red, the occlusion TF's colours (tan organs, ivory
/// bone), the amber object-space lines (against the same scene with `--style none`), and a context
/// that importance modulation changes (against `--gamma 0`, colour unmodulated). Thresholds are
/// about half of what lavapipe gives at 512².
#[test]
fn the_composed_chest_shows_all_four_techniques() {
    let dir = tempfile::tempdir().unwrap();
    let scene = example("chest_composed.json");
    let render = |name: &str, extra: &[&str]| {
        let out = dir.path().join(name);
        let mut args = vec!["render", "--scene", scene.to_str().unwrap()];
        args.extend(["--size", "512x512"]);
        args.extend_from_slice(extra);
        args.extend(["--out", out.to_str().unwrap()]);
        let o = common::vellum(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        image::open(&out).unwrap().to_rgb8()
    };
    let picture = render("composed.png", &[]);
    let count = |f: &dyn Fn([f32; 3]) -> bool| {
        picture
            .pixels()
            .filter(|p| f(p.0.map(|c| c as f32 / 255.0)))
            .count()
    };
    let red = count(&|[r, g, b]| r > 0.45 && g < 0.6 * r && b < 0.6 * r);
    let tan = count(&|[r, g, b]| r > 0.2 && r > g && g > b && b < 0.7 * r && g > 0.55 * r);
    let ivory = count(&|[r, g, b]| r > 0.7 && g > 0.65 && b > 0.55 && r >= b);
    // Pixels where two pictures differ by more than `by` in some channel, and where the first
    // is the greener by more than `by` (amber over red).
    let differ = |other: &image::RgbImage, by: u8, greener: bool| {
        picture
            .pixels()
            .zip(other.pixels())
            .filter(|(a, b)| match greener {
                true => a.0[1] > b.0[1].saturating_add(by),
                false => a.0.iter().zip(b.0).any(|(x, y)| x.abs_diff(y) > by),
            })
            .count()
    };
    let lines = differ(&render("no_lines.png", &["--style", "none"]), 40, true);
    let modulated = differ(&render("unmodulated.png", &["--gamma", "0"]), 8, false);
    eprintln!("composed chest at 512²: red {red}, tan {tan}, ivory {ivory}, line pixels {lines}, modulated {modulated}");
    assert!(red > 1500, "the heart's colour ({red} pixels)");
    assert!(tan > 3000, "the occlusion TF's organs ({tan} pixels)");
    assert!(ivory > 1500, "the occlusion TF's bone ({ivory} pixels)");
    assert!(lines > 150, "the lines ({lines} pixels)");
    assert!(
        modulated > 5000,
        "importance modulation changes the context ({modulated} pixels)"
    );
}
