//! `vellum render`.

use crate::args::*;
use crate::commands::{context, inputs_key, passes_json, report_validation, together};
use crate::scene_args::TimeArg;
use anyhow::Result;
use serde_json::json;
use vellum::render::scene::GpuScene;
use vellum::render::session::{Opened, Session, SessionOptions};
use vellum::team::Team;

pub(crate) fn lines(cli: &Cli, a: &LinesArgs) -> Result<()> {
    use vellum::render::frame::Renderer;
    use vellum::render::targets::to_rgb8;
    let (style, both) = match a.kind.as_str() {
        "silhouettes" => ("silhouettes", false),
        "suggestive" => ("suggestive", false),
        "both" => ("silhouettes", true),
        k => anyhow::bail!("--kind {k:?} is unknown; expected silhouettes, suggestive or both"),
    };
    anyhow::ensure!(
        a.render.scene.style.style.is_none(),
        "lines takes --kind, not --style; the style is the lines"
    );
    let out = a
        .render
        .out
        .as_deref()
        .ok_or_else(|| anyhow::anyhow!("lines needs --out image.png"))?;
    // The style flags (edge colour, width, line parameters) apply to the lines' style.
    let mut args = a.render.scene.clone();
    args.style.style = Some(style.into());
    let mut scene = args.scene("lines")?;
    let mut params = scene.style.take().map(|s| s.params).unwrap_or_default();
    params.line_both = both;
    scene.style = Some(vellum::render::scene::StyleSpec {
        style: serde_json::Value::String(style.into()),
        params,
    });
    let classification = scene.classification()?;
    let ctx = context(cli)?;
    let budget = vellum::render::bricked::gpu_budget_bytes(&ctx, a.render.gpu_budget)?;
    let input = (scene.input.path.as_str(), scene.input.pick());
    let budget = (budget, Some("--gpu-budget"));
    let v = vellum::render::session::in_core_only(input, budget, "lines", || scene.load_volume())?;
    let view = scene.view(v.geometry.is_oriented())?;
    let modulation = scene.modulation.clone().unwrap_or_default();
    let mut gpu = GpuScene::prepare(&ctx, &v, &classification, scene.focus, &modulation)?;
    let mut renderer = Renderer::new(&ctx)?;
    let frame = renderer.render_frame(&gpu.volume, &mut gpu.classify, &view, true)?;
    report_validation(&ctx);
    let (segments, found) = frame.segments.clone().unwrap_or_default();
    let raster = frame
        .lines
        .ok_or_else(|| anyhow::anyhow!("the frame drew no lines; give a focus with --iso V"))?;
    let depth = frame
        .layers
        .as_ref()
        .map(|l| l.focus_depth.clone())
        .ok_or_else(|| anyhow::anyhow!("lines need a two-level frame; drop --one-pass"))?;
    let [w, h] = frame.size;
    // Visible pieces per kind, in the PNG's pixel coordinates.
    let mut pieces: [Vec<Vec<[f32; 2]>>; 2] = [Vec::new(), Vec::new()];
    for seg in &segments {
        let k = (seg.kind() > 0.5) as usize;
        pieces[k].extend(raster.visible_pieces(seg, &depth, [w, h]));
    }
    vellum::output::write_png_rgb(out, w, h, &to_rgb8(&frame.composite, scene.background))?;
    if let Some(path) = &a.render.exr {
        frame.write_exr(path)?;
    }
    if let Some(path) = &a.svg {
        let p = &scene.style.as_ref().map(|s| s.params).unwrap_or_default();
        let group = |id, paths| vellum::output::SvgGroup {
            id,
            colour: p.edge_color,
            width: p.edge_width,
            paths,
        };
        vellum::output::write_svg_lines(
            path,
            [w, h],
            &format!("vellum lines of {}: visible parts only", scene.input.path),
            &[
                group("silhouettes", &pieces[0]),
                group("suggestive-contours", &pieces[1]),
            ],
        )?;
    }
    let stored = segments.len() as u64;
    let report = json!({
        "device": ctx.info.name,
        "kind": a.kind,
        "segments_found": found,
        "segments_stored": stored,
        "overflowed": found > stored,
        "silhouette_segments": segments.iter().filter(|s| s.kind() < 0.5).count(),
        "suggestive_segments": segments.iter().filter(|s| s.kind() > 0.5).count(),
        "visible_paths": [pieces[0].len(), pieces[1].len()],
        "passes": passes_json(&frame.passes),
    });
    if a.render.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        println!(
            "lines of {} ({w}x{h}) on {}: {found} segments ({} silhouette, {} suggestive), {} visible paths",
            scene.input.path,
            ctx.info.name,
            report["silhouette_segments"],
            report["suggestive_segments"],
            pieces[0].len() + pieces[1].len()
        );
        if found > stored {
            println!("  the buffer held {stored} of them; the rest were dropped");
        }
    }
    Ok(())
}

pub(crate) fn render((cli, team): (&Cli, &dyn Team), a: &RenderArgs) -> Result<()> {
    if a.scene.time == Some(TimeArg::All) {
        return render_every_time((cli, team), a);
    }
    render_on(None, (cli, team), a).map(|_| ())
}

/// The frames of `render --time all`: one device, and time point 0's intensity scale and
/// classification (`render::session::series_scale`), taken from its frame so that no later frame
/// reads time point 0 again.
struct Series {
    ctx: std::sync::Arc<vellum::gpu::Context>,
    /// Time point 0's range and `auto` line smoothing, with its classification.
    scale: Option<([f64; 2], u32, vellum::classify::Classification)>,
    /// Time point 0's scales of the channels mixed, read once.
    channel_scales: Option<Vec<vellum::classify::channels::ChannelScale>>,
}

impl Series {
    /// Draws `scene` on the series' scales once they are taken (from the second frame on).
    fn give_scales(
        &self,
        scene: &mut vellum::render::scene::Scene,
        classification: &mut vellum::classify::Classification,
    ) {
        if let Some((range, line_smooth, c)) = self.scale.clone() {
            scene.input.range = Some(range);
            scene.input.line_smooth = Some(line_smooth);
            *classification = c;
        }
        if let (Some(spec), Some(scales)) = (scene.channels.as_mut(), &self.channel_scales) {
            spec.scales = scales.clone();
        }
    }

    /// Time point 0's scales, taken from the first frame's `input` (opened) and `scene`.
    fn take_scales(
        &mut self,
        scene: &vellum::render::scene::Scene,
        input: &Opened,
        classification: &vellum::classify::Classification,
    ) -> Result<()> {
        if self.scale.is_none() {
            self.take_scale(input, classification)?;
        }
        if let (Some(spec), None) = (&scene.channels, &self.channel_scales) {
            // Read as this first frame read them: through the brick cache, from small levels.
            let paged = matches!(input, Opened::Bricked(_));
            let path = std::path::Path::new(&scene.input.path);
            self.channel_scales = Some(spec.series_scales(path, paged)?);
        }
        Ok(())
    }

    /// Time point 0's scale, from its volume in core (a series beyond the GPU budget keeps the
    /// brick cache's own scale).
    fn take_scale(
        &mut self,
        input: &Opened,
        classification: &vellum::classify::Classification,
    ) -> Result<()> {
        let Opened::InCore(v) = input else {
            return Ok(());
        };
        let range = v.normalised_range();
        let c = match classification {
            vellum::classify::Classification::Auto => vellum::classify::Classification::Transfer(
                vellum::classify::window::auto(v, range)?,
            ),
            c => c.clone(),
        };
        let line_smooth = vellum::volume::lines::auto_smooth_radius(v);
        self.scale = Some((range, line_smooth, c));
        Ok(())
    }
}

/// One frame, on the device `series` shares when it is one of a series (which says its lines
/// once, for all its frames, and draws them on one scale), else on a context of its own.
/// Returns whether the input gives its orientation.
fn render_on(
    mut series: Option<&mut Series>,
    (cli, team): (&Cli, &dyn Team),
    a: &RenderArgs,
) -> Result<bool> {
    use vellum::render::targets::to_rgb8;
    let mut scene = a.scene.scene("render")?;
    if let Some(path) = &a.save_scene {
        if team.is_root() {
            scene.save(path)?;
        }
        if a.out.is_none() {
            println!("wrote the scene to {}", path.display());
            return Ok(true);
        }
    }
    let out = a.out.as_deref().ok_or_else(|| {
        anyhow::anyhow!("render needs --out image.png (or only --save-scene FILE)")
    })?;
    // Errors from what a scene file names say which file and which key they came from.
    let from = |key: &str, e: vellum::Error| match &a.scene.file {
        Some(p) => anyhow::anyhow!("scene file {}: {key}: {e}", p.display()),
        None => e.into(),
    };
    let mut classification = scene
        .classification()
        .map_err(|e| from("classification", e))?;
    if let Some(s) = series.as_ref() {
        s.give_scales(&mut scene, &mut classification);
    }
    let opts = session_options(a)?;
    let open = |budget: u64| {
        Opened::open(&scene, None, budget, opts.chunk_cache_bytes).map_err(|e| from("input", e))
    };
    let (ctx, budget, input) = device_and_input(
        (cli, team),
        series.as_ref().map(|s| s.ctx.clone()),
        a.gpu_budget,
        open,
    )?;
    if let Some(s) = series.as_mut() {
        s.take_scales(&scene, &input, &classification)?;
    }
    let grid = input.grid();
    team.same_inputs(inputs_key(&(&scene.input.path, grid.0)))?;
    let mut view = scene
        .view(grid.2.is_oriented())
        .map_err(|e| from("style", e))?;
    let shared = match team.size() {
        1 => None,
        _ => {
            let weights = together(team, cell_weights(&input, grid.0))?;
            Some(share(team, &mut view, (grid, &weights), a)?)
        }
    };
    let drawn = together(
        team,
        draw(
            &ctx,
            (&scene, &classification),
            &input,
            &mut view,
            (a, budget, &opts),
        ),
    );
    let (frame, prepare_passes, stream, gradients) = drawn?;
    if series.is_none() {
        report_validation(&ctx);
    }
    let (frame, composited) = match shared {
        None => (frame, None),
        Some(s) => match composite(team, &ctx, frame, s)? {
            Some((f, report)) => (f, Some(report)),
            None => return Ok(grid.2.is_oriented()),
        },
    };
    let [w, h] = frame.size;
    vellum::output::write_png_rgb(out, w, h, &to_rgb8(&frame.composite, scene.background))?;
    if let Some(path) = &a.exr {
        frame.write_exr(path)?;
    }
    let passes: Vec<_> = prepare_passes.iter().chain(&frame.passes).collect();
    if series.is_some() {
        return Ok(grid.2.is_oriented());
    }
    if a.json {
        let map = passes_json(passes.iter().copied());
        println!(
            "{}",
            serde_json::to_string_pretty(
                &json!({ "device": ctx.info.name, "size": frame.size, "slices": frame.slices, "passes": map, "bricks": stream, "gradients": gradients,
                    "ranks": team.size(), "compositing": composited,
                    "peak_rss_mib": vellum::memory::peak_resident_kib().map(|k| k as f64 / 1024.0),
                    "peak_heap_mib": vellum::memory::peak_heap_mib(),
                    "peak_device_mib": ctx.peak_allocated_bytes() as f64 / (1 << 20) as f64 })
            )?
        );
    } else {
        println!(
            "rendered {} ({w}x{h}, {} slices) on {}",
            scene.input.path, frame.slices, ctx.info.name
        );
        if let Some(r) = &stream {
            println!(
                "  brick cache: {} passes, {} bricks loaded for {} touched ({} of one value, sharing a slot), {:.1} MiB uploaded, {} evicted, {} bricks resident in {} slots ({:.1} MiB pool; bricks of one value share one)",
                r.passes,
                r.bricks_loaded,
                r.bricks_touched,
                r.bricks_shared,
                r.bytes_streamed as f64 / (1 << 20) as f64,
                r.bricks_evicted,
                r.resident,
                r.capacity,
                r.pool_bytes as f64 / (1 << 20) as f64,
            );
            println!(
                "  streaming: {} chunks decoded ({:.0} MiB/s of source voxels), loaders busy {:.0} ms, GPU {:.0} ms, both {:.0}% of the frame; first frame {}, complete {:.0} ms",
                r.chunks_decoded,
                r.source_mib_per_s,
                r.host_ms,
                r.gpu_ms,
                100.0 * r.both_share,
                r.first_frame_ms
                    .map_or("not drawn".into(), |ms| format!("{ms:.0} ms")),
                r.total_ms
            );
            let m = &r.main;
            println!(
                "  main thread over the passes: recording {:.0} ms, waiting for the GPU {:.0} ms, reading the feedback and asking {:.0} ms, waiting for and placing bricks {:.0} ms",
                m.record_ms, m.gpu_wait_ms, m.feedback_ms, m.batch_ms
            );
        }
        if let Some(c) = &composited {
            println!("  composited by {} ranks: {c}", team.size());
        }
        for p in passes {
            println!("  {:<14} {:>9.3} ms", p.name, p.ms);
        }
    }
    // Once, and only on success: a failure says its one sentence alone.
    if !grid.2.is_oriented() {
        eprintln!(
            "note: {}: {}",
            scene.input.path,
            vellum::volume::geometry::Geometry::UNKNOWN_ORIENTATION
        );
    }
    Ok(grid.2.is_oriented())
}

/// A frame, the passes that prepared its volume, what the streaming did, and where its
/// gradients came from (`Prepared::gradients`).
type Drawn = (
    vellum::render::targets::FrameImage,
    Vec<vellum::gpu::PassTime>,
    Option<vellum::render::bricked::StreamReport>,
    &'static str,
);

/// The session's options from the flags: the GPU budget, the level of detail, and the host
/// memory of the brick cache's streaming (seven eighths for decoded chunks, the rest for bricks
/// waiting for the GPU).
/// `render --time all --out DIR/`: one PNG per time point of the store, `DIR/tNNNN.png`, with a
/// progress bar; each is the frame `--time T` draws.
fn render_every_time((cli, team): (&Cli, &dyn Team), a: &RenderArgs) -> Result<()> {
    use vellum::volume::io::ome_zarr;
    let dir = a.out.as_deref().ok_or_else(|| {
        anyhow::anyhow!("render --time all needs --out DIR/, the folder of one PNG per time point")
    })?;
    anyhow::ensure!(
        a.save_scene.is_none(),
        "--save-scene describes one frame; give one time point with --time T"
    );
    let scene = a.scene.base(None, "render")?;
    let path = std::path::Path::new(&scene.input.path);
    anyhow::ensure!(
        ome_zarr::is_store(path),
        "--time all renders every time point of an OME-Zarr store; {} is not one",
        scene.input.path
    );
    let channel = a.scene.channels.as_ref().and_then(|c| c.first().copied());
    let pick = ome_zarr::Pick {
        time: Some(0),
        channel: Some(channel.or(scene.input.channel).unwrap_or(0)),
    };
    let times = ome_zarr::Multiscale::open_picked(path, pick)?.times;
    if team.is_root() {
        std::fs::create_dir_all(dir).map_err(|e| {
            anyhow::anyhow!("{}: the folder could not be made ({e})", dir.display())
        })?;
    }
    // One device for every frame; each time point after the first is drawn on time point 0's
    // scale and transfer function, taken once from its frame.
    let mut series = Series {
        ctx: together(team, context(cli))?,
        scale: None,
        channel_scales: None,
    };
    let bar = vellum::progress::bar(times as u64, "time points");
    let mut oriented = true;
    for t in 0..times {
        let mut one = a.clone();
        one.scene.time = Some(TimeArg::One(t));
        one.out = Some(dir.join(format!("t{t:04}.png")));
        oriented = render_on(Some(&mut series), (cli, team), &one)?;
        bar.inc(1);
    }
    bar.finish_and_clear();
    report_validation(&series.ctx);
    if team.is_root() {
        println!("wrote {times} time points to {}", dir.display());
        if !oriented {
            eprintln!(
                "note: {}: {}",
                scene.input.path,
                vellum::volume::geometry::Geometry::UNKNOWN_ORIENTATION
            );
        }
    }
    Ok(())
}

fn session_options(a: &RenderArgs) -> Result<SessionOptions> {
    let opts = SessionOptions {
        gpu_budget_mib: a.gpu_budget,
        lod: vellum::render::session::Lod::parse(&a.lod)?,
        ..Default::default()
    };
    Ok(opts.with_memory_budget(a.memory_budget, "--memory-budget")?)
}

/// Draws the frame of `view` through the session: in core, or through the brick cache (waiting
/// for its bricks, and writing the refinements when asked).
fn draw(
    ctx: &std::sync::Arc<vellum::gpu::Context>,
    (scene, classification): (
        &vellum::render::scene::Scene,
        &vellum::classify::Classification,
    ),
    input: &Opened,
    view: &mut vellum::render::view::View,
    (a, budget, opts): (&RenderArgs, u64, &SessionOptions),
) -> Result<Drawn> {
    use vellum::render::bricked::StillOptions;
    let mut session = Session::prepare(ctx, scene, classification, input, (budget, opts))?;
    // (The note is said once the frame is drawn: a failure says its one sentence alone.)
    let (drawn, note) = session.view(view.clone());
    *view = drawn;
    if !session.prepared.is_paged()
        && (a.lod != "auto"
            || a.max_wait_ms.is_some()
            || a.progress_frames.is_some()
            || a.first_frame)
    {
        eprintln!("note: --lod, --max-wait-ms, --progress-frames and --first-frame apply to a volume drawn through the brick cache; this one fits the GPU budget and is drawn whole");
    }
    let mut written = 0usize;
    let background = scene.background;
    let mut write = |image: &vellum::render::targets::FrameImage| -> vellum::Result<()> {
        let Some(dir) = &a.progress_frames else {
            return Ok(());
        };
        std::fs::create_dir_all(dir).map_err(|e| vellum::Error::Io {
            path: dir.clone(),
            cause: e,
        })?;
        let [w, h] = image.size;
        let path = dir.join(format!("progress_{written:03}.png"));
        written += 1;
        let rgb = vellum::render::targets::to_rgb8(&image.composite, background);
        vellum::output::write_png_rgb(&path, w, h, &rgb)
    };
    let still = StillOptions {
        max_wait: a.max_wait_ms.map(std::time::Duration::from_millis),
        progress: match a.progress_frames {
            Some(_) => Some(&mut write),
            None => None,
        },
        first_frame: a.first_frame,
        time_whole_frame: a.time_whole_frame,
    };
    // `VELLUM_STREAM_FLOOR=1` (bench scale): the chunks the frame decodes are recorded, and
    // decoded again plainly and uploaded after it, the floor its streaming is judged against.
    // `=paired` also pairs each of the frame's decodes with a plain one beside it.
    let floor_of = match (input, std::env::var("VELLUM_STREAM_FLOOR").as_deref()) {
        (Opened::Bricked(levels), Ok(how @ ("1" | "paired"))) => {
            levels.chunks().record_keys();
            if how == "paired" {
                levels.chunks().pair_decodes();
            }
            Some(levels)
        }
        _ => None,
    };
    let (frame, mut report) = session.still(view, still)?;
    if let Some(note) = note {
        eprintln!("{note}");
    }
    if let (Some(levels), Some(r)) = (floor_of, report.as_mut()) {
        r.floor = Some(vellum::render::stream::Floor::measure(ctx, levels)?);
    }
    if let (Some(r), Some(ms)) = (report.as_ref().filter(|r| !r.complete), a.max_wait_ms) {
        eprintln!(
            "the frame is not complete: --max-wait-ms {ms} ran out after {} passes, so bricks still missing were drawn from coarser levels",
            r.passes
        );
    }
    let gradients = session.prepared.gradients().name();
    Ok((frame, session.prepared.passes().to_vec(), report, gradients))
}

/// This rank's part of a shared frame: the style kept for rank 0, the ranks' order.
struct Share {
    style: Option<vellum::render::style::Style>,
    order: Vec<usize>,
    how: vellum::render::sortlast::Exchange,
    two_level: bool,
}

/// Makes `view` this rank's share of the frame: the ray caster on its region, without the
/// style (rank 0 styles the composited layers).
fn share(
    team: &dyn Team,
    view: &mut vellum::render::view::View,
    (grid, weights): (Grid, &[f64]),
    a: &RenderArgs,
) -> Result<Share> {
    use vellum::render::sortlast::{regions, Exchange};
    let how = match a.composite.as_deref() {
        None | Some("auto") => Exchange::auto(team.size()),
        Some(other) => Exchange::parse(other)?,
    };
    if view.raycast.is_none() {
        if team.is_root() {
            eprintln!("a frame shared by the ranks of a job is ray cast: the ray caster draws it");
        }
        view.raycast = Some(Default::default());
    }
    let (boxes, order) = regions((grid.0, grid.1, &grid.2), view, (team.size(), weights));
    if let Some(r) = view.raycast.as_mut() {
        r.region = Some(boxes[team.rank()]);
    }
    Ok(Share {
        style: view.style.take(),
        order,
        how,
        two_level: !view.one_pass,
    })
}

/// Composites the ranks' partial frames; rank 0 styles the result and gets the frame and a
/// report of the compositing, the others `None`.
fn composite(
    team: &dyn Team,
    ctx: &std::sync::Arc<vellum::gpu::Context>,
    frame: vellum::render::targets::FrameImage,
    s: Share,
) -> Result<Option<(vellum::render::targets::FrameImage, serde_json::Value)>> {
    use vellum::render::sortlast;
    let size = frame.size;
    let (whole, cost) = sortlast::composite(team, s.how, sortlast::pack(&frame), &s.order)?;
    let mut sent = [cost.bytes_sent];
    team.sum(&mut sent);
    let Some(whole) = whole else {
        return Ok(None);
    };
    let (pixels, layers) = sortlast::unpack(&whole, s.two_level);
    let styled = match (&s.style, &layers) {
        (Some(style), Some(l)) => {
            let mut r = vellum::render::frame::Renderer::new(ctx)?;
            Some(r.style_layers((l, &pixels), size, style)?)
        }
        _ => None,
    };
    let out = match styled {
        Some(mut f) => {
            f.passes = frame.passes.iter().chain(&f.passes).cloned().collect();
            f
        }
        None => vellum::render::targets::FrameImage {
            composite: pixels,
            layers,
            ..frame
        },
    };
    let report = json!({
        "exchange": s.how.name(), "ms": cost.seconds * 1e3, "over_ms": cost.over_seconds * 1e3,
        "bytes_sent": sent[0],
    });
    Ok(Some((out, report)))
}

/// The device (the series' when there is one), the GPU budget in bytes and the input `open`
/// opened within it. With `--gpu-budget` given the budget needs no device, so a new device is made on a
/// thread while the input opens: its start (about 60 ms on lavapipe) hides behind the store's
/// metadata and small level, several round trips from a server.
fn device_and_input(
    (cli, team): (&Cli, &dyn Team),
    device: Option<std::sync::Arc<vellum::gpu::Context>>,
    gpu_budget: Option<f64>,
    open: impl FnOnce(u64) -> Result<Opened>,
) -> Result<(std::sync::Arc<vellum::gpu::Context>, u64, Opened)> {
    use vellum::render::bricked::{gpu_budget_bytes, gpu_budget_bytes_of};
    if let Some(ctx) = device {
        let budget = gpu_budget_bytes(&ctx, gpu_budget)?;
        return Ok((ctx, budget, together(team, open(budget))?));
    }
    let Some(mib) = gpu_budget else {
        let ctx = together(team, context(cli))?;
        let budget = gpu_budget_bytes(&ctx, None)?;
        return Ok((ctx, budget, together(team, open(budget))?));
    };
    let budget = gpu_budget_bytes_of(mib)?;
    let (ctx, input) = std::thread::scope(|s| {
        let made = s.spawn(|| context(cli));
        let input = open(budget);
        let ctx = made
            .join()
            .unwrap_or_else(|_| Err(anyhow::anyhow!("making the device panicked")));
        (ctx, input)
    });
    let ctx = together(team, ctx)?;
    Ok((ctx, budget, together(team, input)?))
}

/// Level 0's dims, spacing and placement.
type Grid = ([usize; 3], [f64; 3], vellum::volume::geometry::Geometry);

/// The weights the ranks' regions balance (`sortlast::cell_weights`): from the volume in core,
/// or from a level of at most 64³ voxels of the pyramid.
fn cell_weights(input: &Opened, dims: [usize; 3]) -> Result<Vec<f64>> {
    let small = input.small(1 << 18)?;
    Ok(vellum::render::sortlast::cell_weights(&small, dims))
}
