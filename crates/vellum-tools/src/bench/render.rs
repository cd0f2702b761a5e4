//! `vellum bench render` (SPEC TL8, two-level paper Fig. 9): frame rates of the slice renderer with
//! persistent GPU state and frames in flight.
//!
//! - **Levels:** one pass against two levels, frames alternating, and the two-level overhead in
//!   percent (the paper measured 16–40 %). Frame time is the sum of the frame's GPU passes
//!   (`one_pass`, or `focus` + `context` + `composite`), after a warm-up frame.
//! - **Orbit:** 36 two-level frames with the camera turning 10° a frame, recorded into a ring of
//!   2 frames in flight with persistent targets. It reports the median GPU ms per frame, the median
//!   host ms spent recording and submitting a frame, the fps over the whole orbit (wall clock,
//!   which on a CPU device is the GPU time plus whatever the host does meanwhile), and the GPU
//!   memory allocations made after the first frame (0 is the design); then the same orbit drawn
//!   by the ray caster, the viewer's renderer.
//! - **Modulation:** the two-level frame again with colour modulation by ΔD (one more 3D texture
//!   fetch per shaded sample), interleaved with the plain frames; its extra cost in percent.
//! - **Edits:** frames that change the transfer function between frames (only its 4 KiB texture is
//!   re-uploaded) against frames that re-prepare the scene (upload the volume, recompute normals).
//!
//! Data: the CT head (cthead_stanford, 256×256×113, iso 1300 with ct-skin-bone) and the engine
//! (256×256×128, iso 180 with grey) from ../shared/data; without the data, the Shepp–Logan
//! phantom stands in and the row says so.

use crate::bench::{median, shared_data};
use serde::Serialize;
use std::sync::Arc;
use std::time::Instant;
use vellum_error::{Error, Result};
use vellum_gpu::{Context, FrameResult, Frames, FramesDesc, PassTime};
use vellum_render::classify::modulation::Modulation;
use vellum_render::classify::transfer::TransferFunction;
use vellum_render::classify::{Classification, Focus};
use vellum_render::render::camera::Camera;
use vellum_render::render::frame::Renderer;
use vellum_render::render::scene::GpuScene;
use vellum_render::render::targets::FrameTargets;
use vellum_render::render::view::{Lighting, View};
use vellum_volume::{io, phantom, Volume};

/// Options of `vellum bench render`.
#[derive(Clone, Debug)]
pub struct Options {
    pub repeat: usize,
    pub sizes: Vec<u32>,
    /// Frames of the orbit (36 turns the camera once around).
    pub orbit_frames: usize,
    /// `bench styles`: draw the levels with the ray caster (the viewer's default) instead of the
    /// slicer.
    pub raycast: bool,
}

/// One row: a volume at one size.
#[derive(Clone, Debug, Serialize)]
pub struct Row {
    pub data: String,
    pub size: u32,
    pub slices: u32,
    pub one_pass_ms: f64,
    pub two_level_ms: f64,
    pub one_pass_fps: f64,
    pub two_level_fps: f64,
    /// Median over frame pairs of (two-level − one-pass) / one-pass, in percent; the frames of a
    /// pair run back to back.
    pub overhead_percent: f64,
    /// Median ms of the two-level frame with colour modulation (abs, Phong, γ 0.5) by ΔD (R = 10).
    pub modulated_ms: f64,
    /// Median over frame triples of (modulated − two-level) / two-level, in percent.
    pub modulation_percent: f64,
    /// Median ms of each pass of the two-level frame.
    pub focus_ms: f64,
    pub context_ms: f64,
    pub composite_ms: f64,
    /// Median ms of the ray caster's one-pass and two-level frames (same planes, default options).
    pub raycast_one_pass_ms: f64,
    pub raycast_two_level_ms: f64,
    /// Median over frame groups of ray-cast / sliced two-level ms (below 1: the ray caster is
    /// faster).
    pub raycast_ratio: f64,
}

/// One orbit: a volume at one size, two levels, frames in flight.
#[derive(Clone, Debug, Serialize)]
pub struct OrbitRow {
    pub data: String,
    pub size: u32,
    pub frames: usize,
    pub frames_in_flight: usize,
    /// Median GPU ms per frame (sum of the frame's timed passes).
    pub gpu_ms: f64,
    /// Median host ms per frame spent recording and submitting (proxy geometry included).
    pub cpu_record_submit_ms: f64,
    /// Frames over the orbit's wall time.
    pub fps: f64,
    /// GPU memory allocations made after the first frame.
    pub allocations_after_first_frame: u64,
    /// The same orbit drawn by the ray caster (the viewer's renderer): median GPU ms, median host
    /// ms recording and submitting, and frames over the wall time, which is the frame rate a
    /// window gets when neither waits on a display.
    pub raycast_gpu_ms: f64,
    pub raycast_cpu_record_submit_ms: f64,
    pub raycast_fps: f64,
    /// Wall ms per frame when the transfer function changes between frames (only its texture is
    /// re-uploaded), measured like `fps`.
    pub tf_edit_frame_ms: f64,
    /// Bytes uploaded per frame during the transfer-function edits.
    pub tf_edit_upload_bytes: u64,
    /// Wall ms per frame that re-prepares the scene (volume upload, normals) before rendering.
    pub reprepare_frame_ms: f64,
}

/// The table.
#[derive(Clone, Debug, Serialize)]
pub struct Table {
    pub device: String,
    pub repeat: usize,
    /// ms of `sobel_normals` per volume, computed once before the frames.
    pub normals_ms: Vec<(String, f64)>,
    pub rows: Vec<Row>,
    pub orbit: Vec<OrbitRow>,
    /// The VTK comparison, with `--peer vtk`.
    pub peer: Option<PeerTable>,
}

fn volume(name: &str) -> Result<(Volume, String)> {
    if let Some(root) = shared_data() {
        let path = root.join("volumes").join(name).join(format!("{name}.nhdr"));
        if path.exists() {
            return Ok((io::load(&path, None)?, name.to_string()));
        }
    }
    if std::env::var("CI").as_deref() == Ok("true") {
        return Err(Error::Invalid(format!(
            "../shared/data is missing; the render bench needs {name} under CI"
        )));
    }
    Ok((
        phantom::shepp_logan(256),
        format!("shepp-logan 256 (standing in for {name})"),
    ))
}

/// A bench volume: its label (the dataset, or the phantom standing in), the volume, its focus and
/// transfer function.
struct BenchVolume {
    label: String,
    volume: Volume,
    focus: Focus,
    transfer: TransferFunction,
}

/// The CT head (iso 1300, ct-skin-bone) and the engine (iso 180, grey), or phantoms standing in.
fn bench_volumes() -> Result<Vec<BenchVolume>> {
    [
        ("cthead_stanford", 1300.0, "ct-skin-bone"),
        ("engine", 180.0, "grey"),
    ]
    .into_iter()
    .map(|(name, iso, tf)| {
        let (volume, label) = volume(name)?;
        Ok(BenchVolume {
            focus: Focus::Iso(if label == name { iso } else { 0.9 }),
            label,
            volume,
            transfer: TransferFunction::preset(tf)?,
        })
    })
    .collect()
}

fn frame_ms(passes: &[PassTime]) -> f64 {
    passes
        .iter()
        .filter(|p| p.name != "readback")
        .map(|p| p.ms)
        .sum()
}

/// A renderer with persistent state: frames in flight and targets.
struct Session<'a> {
    renderer: &'a mut Renderer,
    frames: Frames,
    targets: FrameTargets,
    scene: &'a mut GpuScene,
}

impl Session<'_> {
    /// Records and submits one frame; returns the slices drawn.
    fn frame(&mut self, view: &View) -> Result<u32> {
        let (renderer, scene, targets) = (&mut *self.renderer, &mut *self.scene, &mut self.targets);
        let (r, _) = self
            .frames
            .frame(|f| renderer.record(f, &scene.volume, &mut scene.classify, view, targets))?;
        Ok(r.slices)
    }

    /// Waits for the frames in flight and returns every completed frame's timings.
    fn drain(&mut self) -> Result<Vec<FrameResult>> {
        self.frames.wait_idle()?;
        Ok(self.frames.take_finished())
    }
}

fn ray_view(size: u32, azimuth: f32, one_pass: bool) -> View {
    View {
        raycast: Some(vellum_render::render::raycast::RayOptions::default()),
        ..view(size, azimuth, one_pass)
    }
}

fn view(size: u32, azimuth: f32, one_pass: bool) -> View {
    View {
        camera: Camera {
            azimuth_deg: azimuth,
            ..vellum_render::render::scene::DEFAULT_CAMERA
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

/// Runs the benchmark.
pub fn run(ctx: &Arc<Context>, opts: &Options) -> Result<Table> {
    let mut renderer = Renderer::new(ctx)?;
    let mut rows = Vec::new();
    let mut orbit = Vec::new();
    let mut normals_ms = Vec::new();
    for b in bench_volumes()? {
        let (v, label, focus, transfer) = (b.volume, b.label, b.focus, b.transfer);
        let classification = Classification::Transfer(transfer.clone());
        // ΔD is attached once; frames switch the modulation on and off.
        let mut scene = GpuScene::prepare(ctx, &v, &classification, focus, &modulated())?;
        scene.classify.modulation = Modulation::default();
        normals_ms.push((
            label.clone(),
            vellum_gpu::profiler::total_ms(&scene.passes, "sobel_normals"),
        ));
        for &size in &opts.sizes {
            let mut s = Session {
                renderer: &mut renderer,
                frames: Frames::new(ctx, &FramesDesc::interactive("bench render"))?,
                targets: FrameTargets::new(ctx),
                scene: &mut scene,
            };
            rows.push(levels(&mut s, &label, size, opts.repeat)?);
            let mut o = orbit_row(&mut s, &label, size, opts.orbit_frames, &transfer)?;
            drop(s);
            o.reprepare_frame_ms = reprepare(ctx, &mut renderer, &v, &classification, focus, size)?;
            log::info!(
                "bench render: {label} {size}² orbit {:.1} fps, GPU {:.1} ms",
                o.fps,
                o.gpu_ms
            );
            orbit.push(o);
        }
    }
    Ok(Table {
        device: ctx.info.name.clone(),
        repeat: opts.repeat,
        normals_ms,
        rows,
        orbit,
        peer: None,
    })
}

/// The modulation the bench measures: colour modulation, one more ΔD fetch per shaded sample and
/// no change to which samples are drawn. (Opacity modulation changes the work itself: with the
/// paper's t_l = 1 it makes faint samples transparent, which are then discarded, and the engine's
/// frame ran 57 % faster on the H100.)
fn modulated() -> Modulation {
    use vellum_render::classify::modulation::{ColorMode, ColorModulation};
    Modulation {
        color: Some(ColorModulation {
            mode: ColorMode::Abs,
            gamma: 0.5,
        }),
        ..Modulation::default()
    }
}

/// One pass, two levels and two modulated levels, alternating frame by frame so that all see the
/// same machine: CPU devices drift in speed over seconds.
fn levels(s: &mut Session, label: &str, size: u32, repeat: usize) -> Result<Row> {
    let (one_view, two_view) = (view(size, 30.0, true), view(size, 30.0, false));
    let (ray_one, ray_two) = (ray_view(size, 30.0, true), ray_view(size, 30.0, false));
    let triple = |s: &mut Session| -> Result<u32> {
        s.scene.classify.modulation = Modulation::default();
        let slices = s.frame(&one_view)?;
        s.frame(&two_view)?;
        s.scene.classify.modulation = modulated();
        s.frame(&two_view)?;
        s.scene.classify.modulation = Modulation::default();
        s.frame(&ray_one)?;
        s.frame(&ray_two)?;
        Ok(slices)
    };
    let slices = triple(s)?;
    s.drain()?;
    for _ in 0..repeat {
        triple(s)?;
    }
    let done = s.drain()?;
    let by = |k: u64| -> Vec<&FrameResult> { done.iter().filter(|r| r.index % 5 == k).collect() };
    let (one, two, modd, r_one, r_two) = (by(0), by(1), by(2), by(3), by(4));
    let ray_ratios: Vec<f64> = two
        .iter()
        .zip(&r_two)
        .map(|(t, r)| frame_ms(&r.passes) / frame_ms(&t.passes))
        .collect();
    let ratios: Vec<f64> = one
        .iter()
        .zip(&two)
        .map(|(o, t)| frame_ms(&t.passes) / frame_ms(&o.passes))
        .collect();
    let mod_ratios: Vec<f64> = two
        .iter()
        .zip(&modd)
        .map(|(t, m)| frame_ms(&m.passes) / frame_ms(&t.passes))
        .collect();
    let ms =
        |f: &[&FrameResult]| median(&f.iter().map(|r| frame_ms(&r.passes)).collect::<Vec<_>>());
    let (one_ms, two_ms) = (ms(&one), ms(&two));
    let pass = |n: &str| {
        median(
            &two.iter()
                .map(|r| vellum_gpu::profiler::total_ms(&r.passes, n))
                .collect::<Vec<_>>(),
        )
    };
    Ok(Row {
        data: label.to_string(),
        size,
        slices,
        one_pass_ms: one_ms,
        two_level_ms: two_ms,
        one_pass_fps: 1000.0 / one_ms,
        two_level_fps: 1000.0 / two_ms,
        overhead_percent: 100.0 * (median(&ratios) - 1.0),
        modulated_ms: ms(&modd),
        modulation_percent: 100.0 * (median(&mod_ratios) - 1.0),
        focus_ms: pass("focus"),
        context_ms: pass("context"),
        composite_ms: pass("composite"),
        raycast_one_pass_ms: ms(&r_one),
        raycast_two_level_ms: ms(&r_two),
        raycast_ratio: median(&ray_ratios),
    })
}

/// The orbit and the transfer-function edits, on the session's persistent state.
fn orbit_row(
    s: &mut Session,
    label: &str,
    size: u32,
    frames: usize,
    base: &TransferFunction,
) -> Result<OrbitRow> {
    let ctx = s.renderer_context();
    let slicer = orbit(s, frames, |az| view(size, az, false))?;
    let raycast = orbit(s, frames, |az| ray_view(size, az, false))?;

    // Transfer-function edits: the opacity of every point scaled up and down between frames,
    // after a slicer frame that is not timed (the orbit before drew with the ray caster).
    s.frame(&view(size, 0.0, false))?;
    s.drain()?;
    let uploads_before = uploaded_bytes(&ctx);
    let edits = frames.min(12);
    let start = Instant::now();
    for i in 0..edits {
        let scale = if i % 2 == 0 { 0.9 } else { 1.0 };
        let mut tf = base.clone();
        tf.points.iter_mut().for_each(|p| p.rgba[3] *= scale);
        s.scene.classify.set_transfer(&tf);
        s.frame(&view(size, 0.0, false))?;
    }
    s.drain()?;
    let tf_edit_frame_ms = start.elapsed().as_secs_f64() * 1e3 / edits.max(1) as f64;
    let tf_edit_upload_bytes = (uploaded_bytes(&ctx) - uploads_before) / edits.max(1) as u64;
    s.scene.classify.set_transfer(base);
    Ok(OrbitRow {
        data: label.to_string(),
        size,
        frames,
        frames_in_flight: s.frames.len(),
        gpu_ms: slicer.gpu_ms,
        cpu_record_submit_ms: slicer.host_ms,
        fps: slicer.fps,
        allocations_after_first_frame: slicer.allocations + raycast.allocations,
        raycast_gpu_ms: raycast.gpu_ms,
        raycast_cpu_record_submit_ms: raycast.host_ms,
        raycast_fps: raycast.fps,
        tf_edit_frame_ms,
        tf_edit_upload_bytes,
        reprepare_frame_ms: 0.0,
    })
}

/// What one orbit measured.
struct Orbit {
    gpu_ms: f64,
    host_ms: f64,
    fps: f64,
    allocations: u64,
}

/// `frames` frames of `view` with the camera turning 10° a frame, after a first frame that may
/// allocate (targets, staging growth); the rest must not.
fn orbit(s: &mut Session, frames: usize, view: impl Fn(f32) -> View) -> Result<Orbit> {
    let ctx = s.renderer_context();
    s.frame(&view(0.0))?;
    s.drain()?;
    let allocations = ctx.allocation_count();
    let start = Instant::now();
    let mut host = Vec::new();
    for i in 1..=frames {
        s.frame(&view(10.0 * i as f32))?;
        host.push(s.frames.host_times().record_submit_ms);
    }
    let done = s.drain()?;
    let wall = start.elapsed().as_secs_f64();
    Ok(Orbit {
        gpu_ms: median(&done.iter().map(|r| frame_ms(&r.passes)).collect::<Vec<_>>()),
        host_ms: median(&host),
        fps: frames as f64 / wall,
        allocations: ctx.allocation_count() - allocations,
    })
}

impl Session<'_> {
    fn renderer_context(&self) -> Arc<Context> {
        self.renderer.context().clone()
    }
}

fn uploaded_bytes(ctx: &Context) -> u64 {
    ctx.transfers().values().map(|t| t.upload_bytes).sum()
}

/// Wall ms per frame when every frame re-prepares the scene: volume upload, normals, then render.
fn reprepare(
    ctx: &Arc<Context>,
    renderer: &mut Renderer,
    v: &Volume,
    classification: &Classification,
    focus: Focus,
    size: u32,
) -> Result<f64> {
    const FRAMES: usize = 3;
    let start = Instant::now();
    for _ in 0..FRAMES {
        let mut scene = GpuScene::prepare(ctx, v, classification, focus, &Modulation::default())?;
        let mut s = Session {
            renderer: &mut *renderer,
            frames: Frames::new(ctx, &FramesDesc::interactive("bench re-prepare"))?,
            targets: FrameTargets::new(ctx),
            scene: &mut scene,
        };
        s.frame(&view(size, 0.0, false))?;
        s.drain()?;
    }
    Ok(start.elapsed().as_secs_f64() * 1e3 / FRAMES as f64)
}

impl Table {
    /// The table as text.
    pub fn to_text(&self) -> String {
        let mut s = format!(
            "Slice renderer frame rate on {}, median of {} frame(s)\n",
            self.device, self.repeat
        );
        for (d, ms) in &self.normals_ms {
            s += &format!("sobel_normals {d}: {ms:.1} ms (once per volume)\n");
        }
        s += "data                 size  slices | one pass ms   fps | two levels ms   fps | overhead | modulated ms  extra | focus  context  composite ms | raycast one ms  two ms  ray/slice\n";
        for r in &self.rows {
            s += &format!(
                "{:<20} {:>4}² {:>6} | {:>11.2} {:>5.1} | {:>13.2} {:>5.1} | {:>7.1}% | {:>12.2} {:>5.1}% | {:>6.2} {:>8.2} {:>10.2} | {:>14.2} {:>7.2} {:>9.2}\n",
                r.data, r.size, r.slices, r.one_pass_ms, r.one_pass_fps, r.two_level_ms, r.two_level_fps, r.overhead_percent, r.modulated_ms, r.modulation_percent, r.focus_ms, r.context_ms, r.composite_ms, r.raycast_one_pass_ms, r.raycast_two_level_ms, r.raycast_ratio
            );
        }
        s +=
            "\nOrbit: two levels, camera turning 10° a frame, persistent state, frames in flight\n";
        s += "data                 size  frames | GPU ms/frame  host record+submit ms |    fps | ray caster GPU ms  host ms     fps | allocs after 1st | TF edit ms/frame (bytes up) | re-prepare ms/frame\n";
        for o in &self.orbit {
            s += &format!(
                "{:<20} {:>4}² {:>6} | {:>12.2} {:>22.3} | {:>6.2} | {:>17.2} {:>8.3} {:>7.1} | {:>16} | {:>16.2} ({:>7}) | {:>19.1}\n",
                o.data, o.size, o.frames, o.gpu_ms, o.cpu_record_submit_ms, o.fps, o.raycast_gpu_ms, o.raycast_cpu_record_submit_ms, o.raycast_fps, o.allocations_after_first_frame, o.tf_edit_frame_ms, o.tf_edit_upload_bytes, o.reprepare_frame_ms
            );
        }
        s
    }
}

/// One style at one size: `vellum bench styles`.
#[derive(Clone, Debug, Serialize)]
pub struct StyleRow {
    pub data: String,
    pub size: u32,
    pub style: u32,
    pub name: String,
    /// Median GPU ms of the whole frame (levels and style passes).
    pub frame_ms: f64,
    pub fps: f64,
    /// Median GPU ms of the style's own passes.
    pub post_ms: f64,
    /// Median GPU ms of each style pass, by name.
    pub passes: Vec<(String, f64)>,
    /// The unstyled one-pass frame at this size, and the two-level overhead of this style's frame
    /// over it in percent.
    pub one_pass_ms: f64,
    pub overhead_percent: f64,
}

/// `vellum bench styles` (two-level paper Fig. 9): the frame rate of every style this build can
/// render, with each style pass's GPU time, beside the one-pass frame.
#[derive(Clone, Debug, Serialize)]
pub struct StylesTable {
    pub device: String,
    /// "slicer" or "raycast": what drew the levels.
    pub renderer: String,
    pub repeat: usize,
    pub rows: Vec<StyleRow>,
}

/// Names of the style passes (render/post.rs).
const POST_PASSES: [&str; 9] = [
    "luminance",
    "blur",
    "sobel",
    "dog",
    "canny",
    "hysteresis",
    "kuwahara",
    "saturation",
    "style_composite",
];

/// Runs `vellum bench styles`: frames of every available style and of the one pass, interleaved
/// round by round, on the CT head and the engine.
pub fn run_styles(ctx: &Arc<Context>, opts: &Options) -> Result<StylesTable> {
    use vellum_render::render::style::{Style, StyleParams, STYLES};
    let mut renderer = Renderer::new(ctx)?;
    let styles: Vec<Style> = STYLES
        .iter()
        .filter(|d| d.available())
        .map(|d| Style {
            def: d,
            params: StyleParams::default(),
        })
        .collect();
    let mut rows = Vec::new();
    for b in bench_volumes()? {
        let (v, label, focus) = (b.volume, b.label, b.focus);
        let classification = Classification::Transfer(b.transfer);
        let mut scene = GpuScene::prepare(ctx, &v, &classification, focus, &Modulation::default())?;
        for &size in &opts.sizes {
            let mut s = Session {
                renderer: &mut renderer,
                frames: Frames::new(ctx, &FramesDesc::interactive("bench styles"))?,
                targets: FrameTargets::new(ctx),
                scene: &mut scene,
            };
            // Round: the one pass, then each style; frame k of a round is variant k.
            let variants = styles.len() + 1;
            let raycast = opts
                .raycast
                .then(vellum_render::render::raycast::RayOptions::default);
            let round = |s: &mut Session| -> Result<()> {
                s.frame(&View {
                    raycast,
                    ..view(size, 30.0, true)
                })?;
                for st in &styles {
                    s.frame(&View {
                        style: Some(*st),
                        raycast,
                        ..view(size, 30.0, false)
                    })?;
                }
                Ok(())
            };
            round(&mut s)?;
            s.drain()?;
            for _ in 0..opts.repeat {
                round(&mut s)?;
            }
            let done = s.drain()?;
            let of = |k: usize| -> Vec<&FrameResult> {
                done.iter()
                    .filter(|r| r.index as usize % variants == k)
                    .collect()
            };
            let one_pass_ms = median(
                &of(0)
                    .iter()
                    .map(|r| frame_ms(&r.passes))
                    .collect::<Vec<_>>(),
            );
            for (k, st) in styles.iter().enumerate() {
                let frames = of(k + 1);
                let frame_ms_med = median(
                    &frames
                        .iter()
                        .map(|r| frame_ms(&r.passes))
                        .collect::<Vec<_>>(),
                );
                let pass = |n: &str| {
                    median(
                        &frames
                            .iter()
                            .map(|r| vellum_gpu::profiler::total_ms(&r.passes, n))
                            .collect::<Vec<_>>(),
                    )
                };
                let passes: Vec<(String, f64)> = POST_PASSES
                    .iter()
                    .map(|n| (n.to_string(), pass(n)))
                    .filter(|(_, ms)| *ms > 0.0)
                    .collect();
                rows.push(StyleRow {
                    data: label.clone(),
                    size,
                    style: st.def.number,
                    name: st.def.name.to_string(),
                    frame_ms: frame_ms_med,
                    fps: 1000.0 / frame_ms_med,
                    post_ms: passes.iter().map(|p| p.1).sum(),
                    passes,
                    one_pass_ms,
                    overhead_percent: 100.0 * (frame_ms_med / one_pass_ms - 1.0),
                });
            }
        }
    }
    Ok(StylesTable {
        device: ctx.info.name.clone(),
        renderer: if opts.raycast { "raycast" } else { "slicer" }.into(),
        repeat: opts.repeat,
        rows,
    })
}

impl StylesTable {
    /// The table as text.
    pub fn to_text(&self) -> String {
        let mut s = format!(
            "Style frame rates on {} ({}), median of {} frame(s); overhead against the one pass\n",
            self.device, self.renderer, self.repeat
        );
        s += "data                 size  style                 | frame ms     fps | style passes ms | vs one pass | passes\n";
        for r in &self.rows {
            let passes: Vec<String> = r
                .passes
                .iter()
                .map(|(n, ms)| format!("{n} {ms:.3}"))
                .collect();
            s += &format!(
                "{:<20} {:>4}² {:>2} {:<18} | {:>8.2} {:>7.1} | {:>15.3} | {:>+10.1}% | {}\n",
                r.data,
                r.size,
                r.style,
                r.name,
                r.frame_ms,
                r.fps,
                r.post_ms,
                r.overhead_percent,
                passes.join(", ")
            );
        }
        s
    }
}

/// One size of the peer comparison: the same one-pass render of the CT head (ct-bone, shading,
/// linear interpolation, about two samples per voxel) by VTK and by both our renderers.
#[derive(Clone, Debug, Serialize)]
pub struct PeerRow {
    pub size: u32,
    /// VTK vtkGPUVolumeRayCastMapper: median wall ms of Render + WaitForCompletion.
    pub vtk_ms: f64,
    /// Ours: median GPU ms of the one-pass frame (slicer, then ray caster).
    pub slicer_ms: f64,
    pub raycast_ms: f64,
    /// Ours, timed as VTK's frames are: median wall ms from recording a ray-caster frame to its
    /// completion, one frame at a time.
    pub raycast_wall_ms: f64,
    /// VTK's time over ours (above 1: we are faster).
    pub vtk_over_slicer: f64,
    pub vtk_over_raycast: f64,
    pub vtk_over_raycast_wall: f64,
}

/// The peer comparison (`bench render --peer vtk`).
#[derive(Clone, Debug, Serialize)]
pub struct PeerTable {
    /// VTK's OpenGL renderer string.
    pub vtk_renderer: String,
    pub frames: usize,
    pub rows: Vec<PeerRow>,
    /// Where VTK's first frame of each size was written.
    pub images: String,
}

/// Runs `benches/vtk_peer.py` on the CT head and our slicer and ray caster on the same view,
/// transfer function and sizes, over the same orbit of `frames` frames.
pub fn vtk_peer(ctx: &Arc<Context>, sizes: &[u32], frames: usize) -> Result<PeerTable> {
    let (v, label) = volume("cthead_stanford")?;
    if label != "cthead_stanford" {
        return Err(Error::Invalid(
            "the VTK peer renders the CT head, which needs ../shared/data (or VELLUM_DATA)".into(),
        ));
    }
    let tf = TransferFunction::preset("ct-bone")?;
    let dir = std::env::temp_dir().join(format!("vellum-vtk-peer-{}", std::process::id()));
    let peer = run_vtk_script(&v, &tf, &dir, sizes, frames)?;

    let mut renderer = Renderer::new(ctx)?;
    let classification = Classification::Transfer(tf);
    let mut scene = GpuScene::prepare(
        ctx,
        &v,
        &classification,
        Focus::None,
        &Modulation::default(),
    )?;
    let mut rows = Vec::new();
    for (i, &size) in sizes.iter().enumerate() {
        let mut s = Session {
            renderer: &mut renderer,
            frames: Frames::new(ctx, &FramesDesc::interactive("bench peer"))?,
            targets: FrameTargets::new(ctx),
            scene: &mut scene,
        };
        let (slicer_ms, raycast_ms) = peer_orbit(&mut s, size, frames)?;
        let raycast_wall_ms = peer_wall(&mut s, size, frames)?;
        let vtk_ms = peer["sizes"][i]["median_ms"].as_f64().unwrap_or(f64::NAN);
        rows.push(PeerRow {
            size,
            vtk_ms,
            slicer_ms,
            raycast_ms,
            raycast_wall_ms,
            vtk_over_slicer: vtk_ms / slicer_ms,
            vtk_over_raycast: vtk_ms / raycast_ms,
            vtk_over_raycast_wall: vtk_ms / raycast_wall_ms,
        });
    }
    Ok(PeerTable {
        vtk_renderer: peer["renderer"].as_str().unwrap_or("").to_string(),
        frames,
        rows,
        images: dir.display().to_string(),
    })
}

/// Writes the volume and transfer function into `dir` for `benches/vtk_peer.py`, runs it, and
/// returns the JSON it printed.
fn run_vtk_script(
    v: &Volume,
    tf: &TransferFunction,
    dir: &std::path::Path,
    sizes: &[u32],
    frames: usize,
) -> Result<serde_json::Value> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let raw = dir.join("cthead.u16");
    std::fs::write(&raw, v.data.as_bytes()).map_err(|e| Error::io(&raw, e))?;
    let tf_path = dir.join("ct-bone.json");
    std::fs::write(&tf_path, tf.to_json()).map_err(|e| Error::io(&tf_path, e))?;
    let list = sizes
        .iter()
        .map(u32::to_string)
        .collect::<Vec<_>>()
        .join(",");
    let out = std::process::Command::new("python3")
        .arg(crate::bench::peer_script("vtk_peer.py"))
        .arg(&raw)
        .args(v.dims.iter().map(|d| d.to_string()))
        .args(v.spacing.iter().map(|s| s.to_string()))
        .arg(&tf_path)
        .arg(&list)
        .arg(frames.to_string())
        .arg(dir)
        .output()
        .map_err(|e| Error::Invalid(format!("the VTK peer could not run python3 ({e})")))?;
    let _ = std::fs::remove_file(&raw);
    if !out.status.success() {
        let last = vellum_error::last_line(&out.stderr);
        return Err(Error::Invalid(format!(
            "the VTK peer failed ({last}); expected python3 with the vtk wheel (pip install vtk)"
        )));
    }
    serde_json::from_slice(&out.stdout)
        .map_err(|e| Error::Invalid(format!("the VTK peer printed no JSON ({e})")))
}

/// Our side of the peer's orbit at one size, the slicer and the ray caster alternating frame by
/// frame after a warm-up: their median GPU ms.
fn peer_orbit(s: &mut Session, size: u32, frames: usize) -> Result<(f64, f64)> {
    s.frame(&view(size, 30.0, true))?;
    s.frame(&ray_view(size, 30.0, true))?;
    s.drain()?;
    for k in 0..frames {
        let az = 40.0 + 10.0 * k as f32;
        s.frame(&view(size, az, true))?;
        s.frame(&ray_view(size, az, true))?;
    }
    let done = s.drain()?;
    let ms = |parity: u64| {
        median(
            &done
                .iter()
                .filter(|r| r.index % 2 == parity)
                .map(|r| frame_ms(&r.passes))
                .collect::<Vec<_>>(),
        )
    };
    Ok((ms(0), ms(1)))
}

/// The ray caster's orbit again, timed as `vtk_peer.py` times VTK's (Render, then
/// WaitForCompletion): the median wall ms from recording each frame to its completion, one frame
/// in flight.
fn peer_wall(s: &mut Session, size: u32, frames: usize) -> Result<f64> {
    let mut wall = Vec::with_capacity(frames);
    for k in 0..frames {
        let t0 = Instant::now();
        s.frame(&ray_view(size, 40.0 + 10.0 * k as f32, true))?;
        s.drain()?;
        wall.push(t0.elapsed().as_secs_f64() * 1e3);
    }
    Ok(median(&wall))
}

impl PeerTable {
    /// The comparison as text.
    pub fn to_text(&self) -> String {
        let mut s = format!(
            "\nPeer: VTK vtkGPUVolumeRayCastMapper on {} against vellum, CT head, ct-bone, one pass, \
             median of {} orbit frames (VTK: wall ms of Render; vellum: GPU ms, and wall ms of a frame \
             recorded and waited for alone)\n",
            self.vtk_renderer, self.frames
        );
        s += "size | VTK ms | slicer ms | ray caster ms | ray caster wall ms | VTK/slicer | VTK/ray caster | VTK/ray caster wall\n";
        for r in &self.rows {
            s += &format!(
                "{:>4}² | {:>6.1} | {:>9.1} | {:>13.1} | {:>18.1} | {:>10.2} | {:>14.2} | {:>19.2}\n",
                r.size,
                r.vtk_ms,
                r.slicer_ms,
                r.raycast_ms,
                r.raycast_wall_ms,
                r.vtk_over_slicer,
                r.vtk_over_raycast,
                r.vtk_over_raycast_wall
            );
        }
        s += &format!("VTK's first frames: {}/vtk_SIZE.png\n", self.images);
        s
    }
}
