//! Shared test helpers: a validated GPU context that fails the test on any validation error or
//! warning, and the path to ../shared/data (required under CI).
#![allow(dead_code)]

use std::path::PathBuf;
use std::sync::Arc;
use vellum::gpu::{Context, ContextDesc};

/// A context with the Khronos validation layer on. Drop the returned guard at the end of the test
/// (or let it fall out of scope): it asserts that no error or warning was reported.
pub struct Gpu {
    pub ctx: Arc<Context>,
}

impl Gpu {
    pub fn new() -> Gpu {
        let ctx = Context::new(&ContextDesc {
            validation: Some(true),
            device: None,
        })
        .expect("a Vulkan device with validation");
        assert!(ctx.validation, "validation must be on in tests");
        Gpu { ctx }
    }
}

impl Drop for Gpu {
    fn drop(&mut self) {
        let m = self.ctx.messages();
        if !std::thread::panicking() {
            assert!(
                m.is_clean(),
                "validation reported {} error(s) and {} warning(s): {:#?}",
                m.errors,
                m.warnings,
                m.messages
            );
        }
    }
}

/// ../shared/data beside the checkout. Under CI=true its absence fails the test loudly; elsewhere
/// the test is skipped with a note.
pub fn shared_data() -> Option<PathBuf> {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data");
    if p.is_dir() {
        return Some(p);
    }
    if std::env::var("CI").as_deref() == Ok("true") {
        panic!("../shared/data is missing; CI requires it");
    }
    eprintln!("note: ../shared/data is missing; skipping");
    None
}

/// A real volume from ../shared/data/volumes by dataset name.
pub fn real_volume(name: &str) -> Option<vellum::volume::Volume> {
    let root = shared_data()?;
    let path = root.join("volumes").join(name).join(format!("{name}.nhdr"));
    Some(vellum::volume::io::load(&path, None).expect("real volume loads"))
}

/// Compares an 8-bit RGB image (`width`×`height`) with the stored reference `file` under
/// tests/reference/ within a mean of 1/255 and a max of 24/255 per channel, or writes it as the new
/// reference when `VELLUM_UPDATE_REFERENCES=1` (look at every one before committing it).
pub fn check_reference(file: &str, width: u32, height: u32, rgb: &[u8]) {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/reference")
        .join(file);
    if std::env::var("VELLUM_UPDATE_REFERENCES").as_deref() == Ok("1") {
        std::fs::create_dir_all(path.parent().expect("a folder")).unwrap();
        vellum::output::write_png_rgb(&path, width, height, rgb).unwrap();
        eprintln!("updated {}", path.display());
        return;
    }
    let stored = image::open(&path)
        .unwrap_or_else(|e| {
            panic!(
                "{}: {e}; regenerate with VELLUM_UPDATE_REFERENCES=1",
                path.display()
            )
        })
        .to_rgb8();
    assert_eq!(
        (stored.width(), stored.height()),
        (width, height),
        "{file}: size"
    );
    let (mut sum, mut max) = (0u64, 0u8);
    for (a, b) in stored.as_raw().iter().zip(rgb) {
        let d = a.abs_diff(*b);
        sum += d as u64;
        max = max.max(d);
    }
    let mean = sum as f64 / rgb.len() as f64;
    assert!(
        mean <= 1.0 && max <= 24,
        "{file}: mean {mean:.3}/255, max {max}/255 against the stored reference"
    );
}

/// Runs the `vellum` binary with `args`, validation on and no backtraces.
pub fn vellum(args: &[&str]) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_vellum"))
        .args(args)
        .env("VELLUM_VALIDATION", "1")
        .env_remove("RUST_BACKTRACE")
        .output()
        .expect("run vellum")
}

/// `vellum convert phantom:SPEC DIR/NAME --chunk CHUNK --levels 2`: a phantom's store, asserted
/// written.
pub fn phantom_store(dir: &std::path::Path, name: &str, spec: &str, chunk: usize) -> PathBuf {
    let root = dir.join(name);
    let phantom = format!("phantom:{spec}");
    let chunk = chunk.to_string();
    let out = vellum(&[
        "convert",
        &phantom,
        root.to_str().unwrap(),
        "--chunk",
        &chunk,
        "--levels",
        "2",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    root
}

/// Asserts failure with exactly one line on stderr, starting "error:" and containing every one of
/// `phrases`, and no panic.
pub fn fails_with_all(out: &std::process::Output, phrases: &[&str]) {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "succeeded: {stderr}");
    assert_ne!(out.status.code(), Some(101), "panicked: {stderr}");
    let lines: Vec<&str> = stderr.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "expected one sentence, got: {stderr}");
    assert!(lines[0].starts_with("error: "), "{stderr}");
    for p in phrases {
        assert!(lines[0].contains(p), "expected '{p}' in {stderr}");
    }
}

/// [`fails_with_all`] for one phrase.
pub fn fails_with(out: &std::process::Output, phrase: &str) {
    fails_with_all(out, &[phrase]);
}

/// Asserts success and parses stdout as JSON.
pub fn ok_json(out: &std::process::Output) -> serde_json::Value {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

/// Renders one styled two-level frame of `v` (classified by `classification`, focus `focus`,
/// `camera` as `--camera` takes it, a square image of `size`) into persistent targets, and
/// returns them with the frame's pass timings.
pub fn styled_frame(
    ctx: &Arc<Context>,
    v: &vellum::volume::Volume,
    classification: &vellum::classify::Classification,
    focus: vellum::classify::Focus,
    camera: &str,
    size: u32,
    style: vellum::render::style::Style,
) -> (
    vellum::render::targets::FrameTargets,
    Vec<vellum::gpu::profiler::PassTime>,
) {
    use vellum::render::frame::Renderer;
    use vellum::render::view::{Lighting, View};
    let mut scene = vellum::render::scene::GpuScene::prepare(
        ctx,
        v,
        classification,
        focus,
        &vellum::classify::modulation::Modulation::default(),
    )
    .unwrap();
    let view = View {
        camera: vellum::render::camera::Camera::parse(camera).unwrap(),
        size: [size, size],
        slices: None,
        one_pass: false,
        lighting: Lighting::default(),
        style: Some(style),
        fit: false,
        raycast: None,
    };
    let mut renderer = Renderer::new(ctx).unwrap();
    let mut targets = vellum::render::targets::FrameTargets::new(ctx);
    let mut frames =
        vellum::gpu::Frames::new(ctx, &vellum::gpu::FramesDesc::one_shot("styled", 32)).unwrap();
    frames
        .frame(|f| renderer.record(f, &scene.volume, &mut scene.classify, &view, &mut targets))
        .unwrap();
    let passes = frames.finish().unwrap();
    (targets, passes)
}

/// Whether python3 imports `modules` (comma-separated, as in an import statement), for tests
/// whose peer is a Python package; under CI its absence fails the test.
/// Runs `python3 tests/support/SCRIPT ARGS...`, which must succeed.
pub fn support_script(script: &str, args: &[&std::ffi::OsStr]) {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/support")
        .join(script);
    let out = std::process::Command::new("python3")
        .arg(path)
        .args(args)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{script}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

pub fn python_with(modules: &str) -> bool {
    let have = std::process::Command::new("python3")
        .args(["-c", &format!("import {modules}")])
        .status()
        .map(|s| s.success())
        .unwrap_or(false);
    if !have {
        assert_ne!(
            std::env::var("CI").as_deref(),
            Ok("true"),
            "python3 with {modules} is required under CI"
        );
        eprintln!("note: python3 with {modules} is missing; skipping");
    }
    have
}

/// Nothing in `dir` but `keep`: no other output, no `.vellum.*` temporary left behind.
pub fn only(dir: &std::path::Path, keep: &[&str]) {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    let mut want: Vec<String> = keep.iter().map(|s| s.to_string()).collect();
    want.sort();
    assert_eq!(names, want, "files left in {}", dir.display());
}

/// Makes a FIFO at `path` (mkfifo).
pub fn mkfifo(path: &std::path::Path) {
    let ok = std::process::Command::new("mkfifo")
        .arg(path)
        .status()
        .unwrap()
        .success();
    assert!(ok, "mkfifo {}", path.display());
}

/// A 160² ray-cast view from `camera` (`"AZ,EL,DIST"`), one pass or two levels, with an
/// image-space `style` and a `jitter` seed if given.
pub fn ray_view(
    camera: &str,
    one_pass: bool,
    style: Option<&str>,
    jitter: Option<u32>,
) -> vellum::render::view::View {
    use vellum::render::style::Style;
    vellum::render::view::View {
        camera: vellum::render::camera::Camera::parse(camera).unwrap(),
        size: [160, 160],
        slices: None,
        one_pass,
        lighting: vellum::render::view::Lighting::default(),
        style: style.map(|s| Style::new(s, Default::default()).unwrap()),
        fit: false,
        raycast: Some(vellum::render::raycast::RayOptions {
            jitter,
            ..Default::default()
        }),
    }
}

/// Mean and max absolute difference of two frames' 8-bit composites over black, in 1/255 units.
pub fn diff8(
    a: &vellum::render::targets::FrameImage,
    b: &vellum::render::targets::FrameImage,
) -> (f64, u8) {
    use vellum::render::targets::to_rgb8;
    let (x, y) = (
        to_rgb8(&a.composite, [0.0; 3]),
        to_rgb8(&b.composite, [0.0; 3]),
    );
    let sum: u64 = x.iter().zip(&y).map(|(p, q)| p.abs_diff(*q) as u64).sum();
    let max = x.iter().zip(&y).map(|(p, q)| p.abs_diff(*q)).max();
    (sum as f64 / x.len() as f64, max.unwrap_or(0))
}
