//! The ray caster against the slicer, on lavapipe with validation on:
//! - identity: at the same planes, with jitter off, the ray-cast one-pass and two-level composites
//!   (and the focus depth) equal the slicer's, on the Shepp-Logan and nested phantoms, the CT head
//!   and the engine. Tolerance: mean ≤ 2/255 per channel over the image, max ≤ 8/255 in any
//!   pixel (observed: mean ≤ 0.06/255, max 3/255). Both sample the same points (where the slicer's planes cross each ray); what differs
//!   is float compositing order (front to back in registers against back to front in a float
//!   target), early termination at 0.99 (at most 0.01 of a pixel), and, at the box's faces and
//!   the bricks' edges, which pixels rasterisation gives a polygon against which ray parameters
//!   fall inside the box (a sample on the edge is in one and not the other: one sample's worth);
//! - the two-level identity (opaque focus: two levels equal one pass) holds for the ray caster;
//! - with equal world steps instead of the slicer's planes, the composite stays within a mean of
//!   2/255 of the slicer's (observed ≤ 1.1/255). No max is asserted there: a thin opaque structure
//!   (the CT head's bone, the phantom's skull) can be hit on one sampling and missed on the other
//!   at a pixel, which moves that pixel by up to its whole value;
//! - empty-space skipping does not change the image (bit for bit), with either sampling;
//! - early termination changes no pixel by more than (1 − ert) × the brightest shaded colour;
//! - reference images of the ray caster;
//! - empty space adds nothing under a ramp from 0 (`grey`): the transfer function's table holds
//!   the function at its knots, so a value of 0 has an opacity of exactly 0, in the slicer and
//!   the ray caster alike.

mod common;

use common::Gpu;
use vellum::classify::modulation::Modulation;
use vellum::classify::transfer::TransferFunction;
use vellum::classify::{Classification, Focus};
use vellum::render::camera::Camera;
use vellum::render::frame::Renderer;
use vellum::render::raycast::{RayOptions, Sampling};
use vellum::render::scene::GpuScene;
use vellum::render::targets::{to_rgb8, FrameImage};
use vellum::render::view::{Lighting, View};
use vellum::volume::{phantom, Volume, VoxelData};

fn view(camera: &str, size: u32, one_pass: bool, raycast: Option<RayOptions>) -> View {
    View {
        camera: Camera::parse(camera).unwrap(),
        size: [size, size],
        slices: None,
        one_pass,
        lighting: Lighting::default(),
        style: None,
        fit: false,
        raycast,
    }
}

/// Mean and max absolute difference of the 8-bit composites over black, in 1/255 units.
fn diff8(a: &FrameImage, b: &FrameImage) -> (f64, u8) {
    let (x, y) = (
        to_rgb8(&a.composite, [0.0; 3]),
        to_rgb8(&b.composite, [0.0; 3]),
    );
    let mut sum = 0u64;
    let mut max = 0u8;
    for (p, q) in x.iter().zip(&y) {
        let d = p.abs_diff(*q);
        sum += d as u64;
        max = max.max(d);
    }
    (sum as f64 / x.len() as f64, max)
}

/// Cases: name, volume, transfer function, focus (an opaque iso focus), camera.
fn cases() -> Vec<(&'static str, Volume, &'static str, Focus, &'static str)> {
    let mut cases = vec![
        (
            "shepp-logan",
            phantom::shepp_logan(64),
            "grey",
            Focus::Iso(0.9),
            "30,20,2.5",
        ),
        (
            "nested",
            phantom::nested(64),
            "grey",
            Focus::Iso(0.6),
            "0,30,2.5",
        ),
    ];
    if let Some(v) = common::real_volume("cthead_stanford") {
        cases.push(("cthead", v, "ct-skin-bone", Focus::Iso(1300.0), "0,0,2.4"));
    }
    if let Some(v) = common::real_volume("engine") {
        cases.push(("engine", v, "grey", Focus::Iso(180.0), "45,30,2.6"));
    }
    cases
}

fn scene(gpu: &Gpu, v: &Volume, tf: &str, focus: Focus) -> GpuScene {
    let tf = Classification::Transfer(TransferFunction::preset(tf).unwrap());
    GpuScene::prepare(&gpu.ctx, v, &tf, focus, &Modulation::default()).unwrap()
}

#[test]
fn ray_casting_matches_slicing_at_the_same_planes() {
    let gpu = Gpu::new();
    let mut renderer = Renderer::new(&gpu.ctx).unwrap();
    let size = 128;
    for (name, v, tf, focus, camera) in cases() {
        let mut s = scene(&gpu, &v, tf, focus);
        for one_pass in [true, false] {
            let mut render = |ray: Option<RayOptions>| {
                renderer
                    .render_frame(
                        &s.volume,
                        &mut s.classify,
                        &view(camera, size, one_pass, ray),
                        true,
                    )
                    .unwrap()
            };
            let slicer = render(None);
            let rays = render(Some(RayOptions::default()));
            let (mean, max) = diff8(&slicer, &rays);
            let level = if one_pass { "one pass" } else { "two levels" };
            println!("{name} {level}: mean {mean:.3}/255, max {max}/255");
            assert!(
                mean <= 2.0 && max <= 8,
                "{name} {level}: mean {mean}/255, max {max}/255"
            );
            // Equal world steps move samples off the planes away from the image centre, and
            // correct opacity for the true step there: a bounded difference, not an identity.
            let world = render(Some(RayOptions {
                sampling: Sampling::WorldSteps,
                ..RayOptions::default()
            }));
            let (wmean, wmax) = diff8(&slicer, &world);
            println!("{name} {level}, world steps: mean {wmean:.3}/255, max {wmax}/255");
            assert!(wmean <= 2.0, "{name} {level} world steps: mean {wmean}/255");
            let names: Vec<&str> = rays.passes.iter().map(|p| p.name.as_str()).collect();
            assert_eq!(names, ["raycast", "readback"], "{name}");
            let lit = rays.composite.iter().filter(|p| p[3] > 0.5).count();
            assert!(lit > 500, "{name} {level}: only {lit} pixels drawn");
            if !one_pass {
                // The focus depth: same nearest focus sample, so the same depth where both have one.
                let (a, b) = (slicer.layers.unwrap(), rays.layers.unwrap());
                let both: Vec<(f32, f32)> = a
                    .focus_depth
                    .iter()
                    .zip(&b.focus_depth)
                    .filter(|(x, y)| x.is_finite() && y.is_finite())
                    .map(|(x, y)| (*x, *y))
                    .collect();
                let close = both.iter().filter(|(x, y)| (x - y).abs() < 1e-4).count();
                let hit = |d: &[f32]| d.iter().filter(|x| x.is_finite()).count();
                println!(
                    "  focus depth: {} / {} pixels equal; covered {} vs {}",
                    close,
                    both.len(),
                    hit(&a.focus_depth),
                    hit(&b.focus_depth)
                );
                assert!(close as f64 >= 0.98 * both.len() as f64, "{name}");
                let (ha, hb) = (hit(&a.focus_depth) as f64, hit(&b.focus_depth) as f64);
                assert!(
                    (ha - hb).abs() <= 0.02 * ha.max(1.0),
                    "{name}: {ha} vs {hb}"
                );
            }
        }
    }
}

#[test]
fn two_levels_equal_one_pass_and_speed_ups_keep_the_image() {
    let gpu = Gpu::new();
    let mut renderer = Renderer::new(&gpu.ctx).unwrap();
    for (name, v, tf, focus, camera) in cases() {
        let mut s = scene(&gpu, &v, tf, focus);
        let mut render = |one_pass: bool, ray: RayOptions| {
            renderer
                .render_frame(
                    &s.volume,
                    &mut s.classify,
                    &view(camera, 96, one_pass, Some(ray)),
                    true,
                )
                .unwrap()
        };
        let base = RayOptions::default();
        let one = render(true, base);
        let two = render(false, base);
        let (mean, max) = diff8(&one, &two);
        println!("{name}: two levels vs one pass: mean {mean:.3}/255, max {max}/255");
        assert!(mean < 1.0 && max <= 8, "{name}: mean {mean}, max {max}");

        for (one_pass, sampling) in [
            (true, Sampling::Planes),
            (false, Sampling::Planes),
            (false, Sampling::WorldSteps),
        ] {
            // One sample at a time (lavapipe's default, named here for any device).
            let base = RayOptions {
                sampling,
                walk_batch: Some(false),
                ..base
            };
            let skip = render(one_pass, base);
            let full = render(
                one_pass,
                RayOptions {
                    skip_empty: false,
                    ..base
                },
            );
            assert_eq!(
                skip.composite, full.composite,
                "{name}: skipping changed the image"
            );
            // The walk four samples at a time (a GPU's default) keeps every layer, bit for bit,
            // against `skip`, walked one sample at a time.
            let batched = render(
                one_pass,
                RayOptions {
                    walk_batch: Some(true),
                    ..base
                },
            );
            let single = &skip;
            let moved = (batched.composite.iter())
                .zip(&single.composite)
                .filter(|(p, q)| p != q)
                .count();
            assert_eq!(moved, 0, "{name}: the batched walk changed {moved} pixels");
            let depth = |f: &FrameImage| f.layers.as_ref().map(|l| l.focus_depth.clone());
            assert_eq!(
                depth(&batched),
                depth(single),
                "{name}: the batched walk moved the depth"
            );
            let exact = render(one_pass, RayOptions { ert: 1.0, ..base });
            let worst = skip
                .composite
                .iter()
                .zip(&exact.composite)
                .flat_map(|(p, q)| (0..4).map(move |c| (p[c] - q[c]).abs()))
                .fold(0.0f32, f32::max);
            // What is left behind a ray at opacity ≥ 0.99 weighs ≤ 0.01, times the brightest
            // shaded colour: ambient + diffuse + specular of the default lighting.
            let l = Lighting::default();
            let bound = 0.01 * (l.ambient + l.diffuse + l.specular) + 1e-4;
            assert!(
                worst <= bound,
                "{name}: early termination moved a pixel by {worst}"
            );
        }
    }
}

#[test]
fn ray_casts_match_reference_images() {
    let gpu = Gpu::new();
    let mut renderer = Renderer::new(&gpu.ctx).unwrap();
    for (name, v, tf, focus, camera) in cases() {
        let mut s = scene(&gpu, &v, tf, focus);
        let jittered = RayOptions {
            jitter: Some(7),
            ..RayOptions::default()
        };
        let f = renderer
            .render_frame(
                &s.volume,
                &mut s.classify,
                &view(camera, 128, false, Some(jittered)),
                true,
            )
            .unwrap();
        let rgb = to_rgb8(&f.composite, [0.0; 3]);
        common::check_reference(
            &format!("raycast/{name}_two_level_jitter.png"),
            128,
            128,
            &rgb,
        );
    }
}

/// `refine_iso`: the depth of a sphere's surface at the image centre, whose ray passes through the
/// sphere's centre, equals the analytic value to 0.05 voxel from every side; without refinement
/// the hit is only known to a plane spacing. The volume is a signed distance field (R − |p|), so
/// trilinear interpolation puts the isosurface where the sphere is.
#[test]
fn refined_isosurface_hits_the_sphere() {
    let gpu = Gpu::new();
    let mut renderer = Renderer::new(&gpu.ctx).unwrap();
    let n = 64usize;
    let r = 0.6f64; // in [-1, 1] coordinates; the box is 1 world unit wide, so 0.3 world units
    let c = |i: usize| (i as f64 + 0.5) / n as f64 * 2.0 - 1.0;
    let data: Vec<f32> = (0..n * n * n)
        .map(|i| {
            let (x, y, z) = (c(i % n), c((i / n) % n), c(i / (n * n)));
            (r - (x * x + y * y + z * z).sqrt()) as f32
        })
        .collect();
    let v = Volume::new([n; 3], [1.0; 3], vellum::volume::VoxelData::F32(data)).unwrap();
    let mut s = scene(&gpu, &v, "grey", Focus::Iso(0.0));
    let voxel = 1.0 / n as f32;
    for camera in ["0,0,2.5", "30,20,2.5", "-120,60,3"] {
        let mut depth_at_centre = |refine_iso: bool, s: &mut GpuScene| {
            let ray = RayOptions {
                refine_iso,
                ..RayOptions::default()
            };
            let f = renderer
                .render_frame(
                    &s.volume,
                    &mut s.classify,
                    &view(camera, 65, false, Some(ray)),
                    true,
                )
                .unwrap();
            f.layers.unwrap().focus_depth[32 * 65 + 32]
        };
        let cam = Camera::parse(camera).unwrap();
        let radius = glam::Vec3::splat(0.5).length();
        let expected = cam.eye(radius).length() - 0.5 * r as f32;
        let refined = depth_at_centre(true, &mut s);
        let plain = depth_at_centre(false, &mut s);
        let (e1, e0) = (
            (refined - expected).abs() / voxel,
            (plain - expected).abs() / voxel,
        );
        println!("{camera}: refined error {e1:.4} voxel, unrefined {e0:.4} voxel");
        assert!(
            e1 < 0.05,
            "{camera}: refined depth {refined} vs {expected} ({e1} voxel)"
        );
    }
}

/// The command line: `--renderer raycast` with its options, saved in and restored from a scene
/// file bit for bit; ray-caster options without the ray caster, and bad values, get a sentence.
#[test]
fn the_command_line_ray_casts() {
    use common::{fails_with, vellum};
    let dir = tempfile::tempdir().unwrap();
    let p = |n: &str| dir.path().join(n).to_string_lossy().into_owned();
    let base = [
        "render",
        "phantom:nested:32",
        "--iso",
        "0.6",
        "--size",
        "48x48",
        "--renderer",
        "raycast",
    ];
    let mut first = base.to_vec();
    let (a, scene, b) = (p("a.png"), p("a.json"), p("b.png"));
    first.extend([
        "--jitter",
        "5",
        "--refine-iso",
        "--out",
        &a,
        "--save-scene",
        &scene,
    ]);
    let out = vellum(&first);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let saved: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&scene).unwrap()).unwrap();
    assert_eq!(saved["raycast"]["jitter"], 5);
    assert_eq!(saved["raycast"]["refine_iso"], true);
    let out = vellum(&["render", "--scene", &scene, "--out", &b]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());

    let png = p("x.png");
    let slicer = ["render", "phantom:nested:32", "--out", &png];
    fails_with(
        &vellum(&[&slicer[..], &["--jitter", "3"]].concat()),
        "add --renderer raycast",
    );
    fails_with(
        &vellum(&[&base[..], &["--ert", "0", "--out", &png]].concat()),
        "expected a value in (0, 1]",
    );
    fails_with(
        &vellum(&[
            "render",
            "phantom:nested:32",
            "--renderer",
            "marching",
            "--out",
            &png,
        ]),
        "expected slicer or raycast",
    );
    // The style gallery on the ray caster.
    let gallery = p("gallery.png");
    let styles = [
        "styles",
        "phantom:nested:32",
        "--iso",
        "0.6",
        "--size",
        "48x48",
        "--out",
    ];
    let out = vellum(&[&styles[..], &[gallery.as_str(), "--renderer", "raycast"]].concat());
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(std::fs::metadata(&gallery).unwrap().len() > 1000);
    fails_with(
        &vellum(&[&styles[..], &[gallery.as_str(), "--renderer", "cone"]].concat()),
        "expected slicer or raycast",
    );
}

/// A cube of 1s in the middle eighth of a 64³ box of 0s, under `grey` (opacity s): every pixel
/// farther than 3 pixels from the cube's own opaque square is transparent, though its ray crosses
/// 64 voxels of 0s. A table sampled at texel centres gave 0 the ramp's opacity at 0.5/256 (0.002 a
/// voxel), which over the box adds up to an alpha of about 0.2 there.
#[test]
fn empty_space_adds_nothing_under_a_ramp_from_zero() {
    let gpu = Gpu::new();
    let mut renderer = Renderer::new(&gpu.ctx).unwrap();
    let n = 64;
    let inside = |i: usize| (28..36).contains(&i);
    let data: Vec<f32> = (0..n * n * n)
        .map(|i| f32::from(inside(i % n) && inside(i / n % n) && inside(i / (n * n))))
        .collect();
    let v = Volume::new([n; 3], [1.0; 3], VoxelData::F32(data)).unwrap();
    let mut s = scene(&gpu, &v, "grey", Focus::None);
    for ray in [None, Some(RayOptions::default())] {
        let mut view = view("0,0,2.5", 128, true, ray);
        view.slices = Some(64);
        let f = renderer
            .render_frame(&s.volume, &mut s.classify, &view, true)
            .unwrap();
        let alpha = |x: usize, y: usize| f.composite[y * 128 + x][3];
        let opaque: Vec<(usize, usize)> = (0..128 * 128)
            .map(|i| (i % 128, i / 128))
            .filter(|&(x, y)| alpha(x, y) > 0.5)
            .collect();
        assert!(!opaque.is_empty(), "the cube is drawn ({ray:?})");
        let lo = |a: fn(&(usize, usize)) -> usize| opaque.iter().map(a).min().unwrap();
        let hi = |a: fn(&(usize, usize)) -> usize| opaque.iter().map(a).max().unwrap();
        let (x0, x1, y0, y1) = (lo(|p| p.0), hi(|p| p.0), lo(|p| p.1), hi(|p| p.1));
        assert!(x1 - x0 < 40, "the cube is small in the frame ({x0}..{x1})");
        let far = |x: usize, y: usize| x + 3 < x0 || x > x1 + 3 || y + 3 < y0 || y > y1 + 3;
        let haze = (0..128 * 128)
            .map(|i| (i % 128, i / 128))
            .filter(|&(x, y)| far(x, y))
            .map(|(x, y)| alpha(x, y))
            .fold(0.0f32, f32::max);
        assert_eq!(haze, 0.0, "empty space drew an alpha of {haze} ({ray:?})");
    }
}
