//! The frame-oriented core on lavapipe with validation (and, under `make test`, synchronization
//! validation) on:
//! - after the first frame of an orbit, further frames allocate no GPU memory;
//! - a transfer-function edit re-uploads the transfer-function texture and nothing else, and a
//!   frame with no edit uploads nothing;
//! - rendering with an occlusion transfer function never reads the occlusion volume back (and
//!   never uploads one: it is computed from the volume texture on the GPU);
//! - objects dropped while a frame still uses them are released once it completes;
//! - a scene file round-trips: save → load → the same render, bit for bit;
//! - no file in vellum-render's passes/ imports its render/.

mod common;

use common::Gpu;
use std::collections::BTreeMap;
use vellum::classify::modulation::Modulation;
use vellum::classify::otf::OcclusionTf;
use vellum::classify::transfer::TransferFunction;
use vellum::classify::{Classification, Focus};
use vellum::gpu::{Frames, FramesDesc, Image, ImageDesc, TransferCount};
use vellum::render::camera::Camera;
use vellum::render::frame::Renderer;
use vellum::render::scene::{GpuScene, InputSpec, Scene};
use vellum::render::targets::{FrameTargets, TargetsReadback};
use vellum::render::view::{Lighting, View};
use vellum::volume::phantom;

fn view(azimuth: f32, size: u32, one_pass: bool) -> View {
    View {
        camera: Camera {
            azimuth_deg: azimuth,
            elevation_deg: 20.0,
            ..Camera::default()
        },
        size: [size, size],
        slices: None,
        one_pass,
        lighting: Lighting::default(),
        style: None,
        fit: false,
        raycast: None,
    }
}

/// A renderer with persistent state for one scene: frames in flight and targets. Fields drop in
/// order, so the renderer's pipelines and the scene's images go while frames may still be in
/// flight: deferred release must hold them (a first version destroyed pipelines at once, and this
/// test binary crashed on lavapipe).
struct Rig {
    renderer: Renderer,
    scene: GpuScene,
    frames: Frames,
    targets: FrameTargets,
}

impl Rig {
    fn new(gpu: &Gpu, v: &vellum::volume::Volume, tf: &str, focus: Focus) -> Rig {
        let ctx = &gpu.ctx;
        let tf = Classification::Transfer(TransferFunction::preset(tf).unwrap());
        Rig {
            renderer: Renderer::new(ctx).unwrap(),
            scene: GpuScene::prepare(ctx, v, &tf, focus, &Modulation::default()).unwrap(),
            frames: Frames::new(ctx, &FramesDesc::interactive("test")).unwrap(),
            targets: FrameTargets::new(ctx),
        }
    }

    /// Records one frame (no readback).
    fn frame(&mut self, v: &View) {
        let (renderer, scene, targets) = (&mut self.renderer, &mut self.scene, &mut self.targets);
        self.frames
            .frame(|f| renderer.record(f, &scene.volume, &mut scene.classify, v, targets))
            .unwrap();
    }
}

/// Transfers that changed between two snapshots, by name.
fn changed(
    before: &BTreeMap<String, TransferCount>,
    after: &BTreeMap<String, TransferCount>,
) -> Vec<String> {
    after
        .iter()
        .filter(|(k, v)| before.get(*k) != Some(v))
        .map(|(k, _)| k.clone())
        .collect()
}

#[test]
fn orbit_allocates_nothing_after_the_first_frame() {
    let gpu = Gpu::new();
    let ctx = &gpu.ctx;
    let mut rig = Rig::new(&gpu, &phantom::shepp_logan(48), "grey", Focus::Iso(0.9));
    for one_pass in [false, true] {
        rig.frame(&view(0.0, 64, one_pass));
    }
    let after_first = ctx.allocation_count();
    for i in 1..=24 {
        let one_pass = i % 5 == 0;
        rig.frame(&view(10.0 * i as f32, 64, one_pass));
        assert_eq!(
            ctx.allocation_count(),
            after_first,
            "frame {i} allocated GPU memory"
        );
    }
    rig.frames.wait_idle().unwrap();
    let done = rig.frames.take_finished();
    assert_eq!(done.len(), 26, "every frame reports its timings once");
    assert!(
        done.windows(2).all(|w| w[0].index < w[1].index),
        "timings come out in order"
    );
    let names: Vec<&str> = done[2].passes.iter().map(|p| p.name.as_str()).collect();
    assert_eq!(names, ["focus", "context", "composite"]);
    assert!(done.iter().all(|r| r.passes.iter().all(|p| p.ms >= 0.0)));
    // A change of size reallocates the targets, once.
    rig.frame(&view(0.0, 80, false));
    let resized = ctx.allocation_count();
    assert!(resized > after_first);
    rig.frame(&view(10.0, 80, false));
    assert_eq!(ctx.allocation_count(), resized);
}

#[test]
fn transfer_function_edit_reuploads_only_its_texture() {
    let gpu = Gpu::new();
    let ctx = &gpu.ctx;
    let mut rig = Rig::new(&gpu, &phantom::nested(40), "grey", Focus::None);
    rig.frame(&view(0.0, 48, false));
    let t0 = ctx.transfers();
    rig.frame(&view(5.0, 48, false));
    let t1 = ctx.transfers();
    assert!(
        changed(&t0, &t1).is_empty(),
        "a frame with no edit uploaded {:?}",
        changed(&t0, &t1)
    );
    rig.scene
        .classify
        .set_transfer(&TransferFunction::preset("ct-bone").unwrap());
    let allocations = ctx.allocation_count();
    rig.frame(&view(5.0, 48, false));
    let t2 = ctx.transfers();
    assert_eq!(changed(&t1, &t2), ["transfer function"]);
    let tf = t2["transfer function"];
    assert_eq!(tf.uploads, t1["transfer function"].uploads + 1);
    assert_eq!(
        tf.upload_bytes - t1["transfer function"].upload_bytes,
        256 * 16
    );
    assert_eq!(
        ctx.allocation_count(),
        allocations,
        "an edit allocates nothing"
    );
    // Setting the same function again changes nothing.
    rig.scene
        .classify
        .set_transfer(&TransferFunction::preset("ct-bone").unwrap());
    rig.frame(&view(5.0, 48, false));
    assert!(changed(&t2, &ctx.transfers()).is_empty());
    rig.frames.wait_idle().unwrap();
}

#[test]
fn occlusion_transfer_function_render_reads_no_volume_back() {
    let gpu = Gpu::new();
    let ctx = &gpu.ctx;
    let before = ctx.transfers();
    let otf = OcclusionTf::load(
        &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/nested_otf.json"),
    )
    .unwrap();
    let v = phantom::nested(48);
    let mut scene = GpuScene::prepare(
        ctx,
        &v,
        &Classification::Occlusion(otf),
        Focus::None,
        &Modulation::default(),
    )
    .unwrap();
    let names: Vec<&str> = scene.passes.iter().map(|p| p.name.as_str()).collect();
    assert_eq!(
        names,
        [
            "upload",
            "sobel_normals",
            "to_float",
            "occlusion",
            "spectrum"
        ]
    );
    assert!(scene.volume.occlusion.is_some());
    // The spectrum (for the viewer's occlusion editor) counts every occlusion voxel once.
    let spectrum = scene
        .spectrum
        .as_ref()
        .expect("the spectrum of the occlusion volume");
    let occ = scene.volume.occlusion.as_ref().unwrap().desc.extent;
    assert_eq!(spectrum.bins, [256, 256]);
    assert_eq!(
        spectrum.counts.iter().map(|&c| c as u64).sum::<u64>(),
        occ.iter().map(|&d| d as u64).product::<u64>()
    );
    let mut renderer = Renderer::new(ctx).unwrap();
    let frame = renderer
        .render_frame(
            &scene.volume,
            &mut scene.classify,
            &view(0.0, 48, false),
            true,
        )
        .unwrap();
    assert!(
        frame.composite.iter().any(|p| p[3] > 0.1),
        "the OTF render shows something"
    );
    let after = ctx.transfers();
    let moved = changed(&before, &after);
    for name in &moved {
        let t = after[name];
        if t.readbacks > 0 {
            assert!(
                [
                    "composite",
                    "focus.phong",
                    "focus.diffuse",
                    "focus.depth",
                    "context"
                ]
                .contains(&name.as_str()),
                "{name} was read back"
            );
        }
        if t.uploads > 0 {
            assert!(
                [
                    "volume intensity",
                    "transfer function",
                    "occlusion transfer function",
                    "dummy occlusion"
                ]
                .contains(&name.as_str()),
                "{name} was uploaded"
            );
        }
    }
    assert_eq!(
        after["volume intensity"].uploads - before.get("volume intensity").map_or(0, |t| t.uploads),
        1
    );
    assert!(
        !after.contains_key("occlusion"),
        "the occlusion volume crossed to the host"
    );
}

#[test]
fn objects_dropped_mid_frame_are_released_when_it_completes() {
    let gpu = Gpu::new();
    let ctx = &gpu.ctx;
    let mut frames = Frames::new(ctx, &FramesDesc::interactive("test release")).unwrap();
    let image = Image::new(
        ctx,
        "released",
        &ImageDesc::new_3d(ash::vk::Format::R32_SFLOAT, [64, 64, 64]),
    )
    .unwrap();
    frames
        .frame(|f| {
            vellum::gpu::commands::clear_image(ctx, f.cmd, &image);
            Ok(())
        })
        .unwrap();
    // The clear may still be running: the image's memory must outlive it.
    drop(image);
    assert!(ctx.pending_releases() <= 1);
    frames.wait_idle().unwrap();
    assert_eq!(
        ctx.pending_releases(),
        0,
        "released once the frame completed"
    );
    // Dropped inside the recording, before the submission exists.
    frames
        .frame(|f| {
            let scratch = Image::new(
                ctx,
                "scratch",
                &ImageDesc::new_3d(ash::vk::Format::R32_SFLOAT, [8, 8, 8]),
            )?;
            vellum::gpu::commands::clear_image(ctx, f.cmd, &scratch);
            Ok(())
        })
        .unwrap();
    assert_eq!(ctx.pending_releases(), 1, "held until its frame completes");
    frames.wait_idle().unwrap();
    assert_eq!(ctx.pending_releases(), 0);
}

#[test]
fn a_scene_file_round_trips_to_the_same_render() {
    let gpu = Gpu::new();
    let ctx = &gpu.ctx;
    let dir = tempfile::tempdir().unwrap();
    let mut scene = Scene::new(InputSpec::new("phantom:shepp-logan:40"));
    scene.focus = Focus::Iso(0.9);
    scene.size = [56, 48];
    scene.camera.azimuth = Some(-40.0);
    scene.lighting.specular = 0.6;
    let path = dir.path().join("scene.json");
    scene.save(&path).unwrap();
    let loaded = Scene::load(&path).unwrap();
    assert_eq!(loaded, scene);
    let mut renderer = Renderer::new(ctx).unwrap();
    let mut render = |s: &Scene| {
        let v = s.load_volume().unwrap();
        let mut g = GpuScene::prepare(
            ctx,
            &v,
            &s.classification().unwrap(),
            s.focus,
            &s.modulation.clone().unwrap_or_default(),
        )
        .unwrap();
        renderer
            .render_frame(
                &g.volume,
                &mut g.classify,
                &s.view(v.geometry.is_oriented()).unwrap(),
                true,
            )
            .unwrap()
    };
    let (a, b) = (render(&scene), render(&loaded));
    let bits = |f: &vellum::render::targets::FrameImage| -> Vec<u32> {
        f.composite.iter().flatten().map(|x| x.to_bits()).collect()
    };
    assert_eq!(bits(&a), bits(&b));
    assert!(a.composite.iter().any(|p| p[3] > 0.5));
}

#[test]
fn persistent_targets_are_read_back_by_name() {
    let gpu = Gpu::new();
    let ctx = &gpu.ctx;
    let mut rig = Rig::new(&gpu, &phantom::nested(32), "grey", Focus::Iso(0.4));
    rig.frame(&view(0.0, 40, false));
    for name in vellum::render::targets::LAYER_NAMES {
        assert!(rig.targets.layer(name).is_some(), "{name}");
    }
    let rb = TargetsReadback::new(ctx, &rig.targets).unwrap();
    let targets = &rig.targets;
    rig.frames
        .frame(|f| {
            rb.record(f, targets);
            Ok(())
        })
        .unwrap();
    rig.frames.wait_idle().unwrap();
    let (composite, layers) = rb.read().unwrap();
    let layers = layers.expect("two-level layers");
    assert_eq!(composite.len(), 40 * 40);
    assert!(layers.focus_depth.iter().any(|d| d.is_finite()));
    // After a one-pass frame only the composite is current.
    rig.frame(&view(0.0, 40, true));
    assert!(rig.targets.layer("composite").is_some() && rig.targets.layer("focus.phong").is_none());
    rig.frames.wait_idle().unwrap();
}

#[test]
fn no_pass_imports_the_renderer() {
    let mut pending =
        vec![std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("crates/vellum-render/src/passes")];
    let mut files = Vec::new();
    while let Some(dir) = pending.pop() {
        for entry in std::fs::read_dir(dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                pending.push(path);
            } else {
                files.push(path);
            }
        }
    }
    assert!(
        files.iter().any(|f| f.ends_with("occlusion_fft/gpu.rs")),
        "sub-folders are walked"
    );
    for path in files {
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(
            !text.contains("crate::render"),
            "{} imports render/",
            path.display()
        );
    }
}

#[test]
fn a_submission_inside_a_recording_is_refused() {
    let gpu = Gpu::new();
    let ctx = &gpu.ctx;
    let mut outer = Frames::new(ctx, &FramesDesc::one_shot("outer", 1)).unwrap();
    let err = outer
        .frame(|_| vellum::gpu::submit_once(ctx, "inner", |_| Ok(())))
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("inner") && err.contains("while another frame is being recorded"),
        "{err}"
    );
    outer.wait_idle().unwrap();
    // The refusal leaves the context as it was: the next recordings go through.
    vellum::gpu::submit_once(ctx, "after", |_| Ok(())).unwrap();
    outer.frame(|_| Ok(())).unwrap();
    outer.wait_idle().unwrap();
}

/// The pipeline cache builds each (shader, constants) pair once, keeps specialisations apart,
/// and refuses a cached shader asked for with another interface.
#[test]
fn the_pipeline_cache_builds_each_variant_once() {
    use vellum::gpu::{BindingKind, PipelineCache, PipelineDesc};
    let gpu = Gpu::new();
    let mut cache = PipelineCache::new(&gpu.ctx);
    let bindings = [
        BindingKind::StorageImage,
        BindingKind::StorageImage,
        BindingKind::StorageBuffer,
    ];
    let push = std::mem::size_of::<vellum::passes::importance::GaussPush>() as u32;
    let gauss = PipelineDesc::new("importance/gauss1d.comp", &bindings, push);
    let r2 = cache.get(&gauss.constants(&[2, 8, 8])).unwrap();
    let again = cache.get(&gauss.constants(&[2, 8, 8])).unwrap();
    assert!(
        std::sync::Arc::ptr_eq(&r2, &again),
        "a hit returns the same pipeline"
    );
    let r3 = cache.get(&gauss.constants(&[3, 8, 8])).unwrap();
    assert!(
        !std::sync::Arc::ptr_eq(&r2, &r3),
        "another radius is another pipeline"
    );
    assert_ne!(r2.raw, r3.raw);
    assert_eq!(cache.len(), 2);
    let wrong = PipelineDesc::new("importance/gauss1d.comp", &bindings[..2], push);
    let e = cache
        .get(&wrong.constants(&[2, 8, 8]))
        .err()
        .expect("refused");
    assert!(e.to_string().contains("importance/gauss1d.comp"), "{e}");
    assert_eq!(cache.len(), 2);
}
