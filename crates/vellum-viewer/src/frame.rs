//! One window frame: egui's panels, the session's requests and edits, the renderer's passes
//! (or the last render presented again), the present pass with egui over it, the GPU timings,
//! and what the frame leaves behind (the streamer's requests, a screenshot).

use super::*;
use vellum_render::render::frame::voxel_planes;

impl PresentPass<'_> {
    pub(crate) fn record(
        &self,
        ctx: &Context,
        cmd: vk::CommandBuffer,
        image: &vellum_gpu::swapchain::Acquired,
        composite: Option<&vellum_gpu::Image>,
        egui_renderer: &mut egui_ash_renderer::Renderer<egui_ash_renderer::allocator::GpuAllocator>,
    ) -> Result<()> {
        let (extent, rect, [r, g, b]) = (self.swapchain.extent, self.ui.rect, self.background);
        if let Some(c) = composite {
            c.transition(cmd, Access::FragmentSampled);
        }
        self.swapchain.record_begin(cmd, image);
        begin_rendering_view(ctx, cmd, image.view, extent, [r, g, b, 1.0]);
        if let Some(c) = composite {
            let push: [f32; 8] = [
                r,
                g,
                b,
                0.0,
                rect[0] as f32,
                rect[1] as f32,
                rect[2] as f32,
                rect[3] as f32,
            ];
            self.present
                .bind(cmd, &[Bind::Sampled(c, self.sampler)], &push, extent)?;
            vellum_gpu::commands::set_scissor(ctx, cmd, rect);
            vellum_gpu::commands::draw(ctx, cmd, None, 3);
        }
        let size = vk::Extent2D {
            width: extent[0],
            height: extent[1],
        };
        egui_renderer
            .cmd_draw(cmd, size, self.ui.ppp, &self.ui.primitives)
            .map_err(|e| Error::Invalid(format!("drawing egui: {e}")))?;
        end_rendering(ctx, cmd);
        self.swapchain.record_end(cmd, image);
        Ok(())
    }
}

impl Running {
    /// Renders and presents one frame (with a screenshot's readback when one is pending).
    /// One window frame: ui → apply → record → present → timings.
    pub(crate) fn redraw(&mut self) -> Result<()> {
        let Some(ui) = self.run_ui()? else {
            return Ok(()); // minimised
        };
        let (view, full) = self.apply_frame(&ui)?;
        let Some(drawn) = self.record_and_present(&ui, view)? else {
            return Ok(()); // the swapchain is out of date: recreated on the next redraw
        };
        self.timings(&drawn)?;
        self.finish_frame(drawn, full)
    }

    /// Runs egui for this frame: the panels edit the model; returns the volume view's rectangle
    /// and egui's triangles, with its textures uploaded.
    pub(crate) fn run_ui(&mut self) -> Result<Option<UiFrame>> {
        let size = self.window.inner_size();
        if size.width == 0 || size.height == 0 {
            return Ok(None);
        }
        if self.resize || self.gpu.swapchain.extent != [size.width, size.height] {
            self.gpu.swapchain.recreate([size.width, size.height])?;
            self.resize = false;
        }
        let raw = self.egui_state.take_egui_input(&self.window);
        let model = &mut self.session.model;
        let show_panel = self.show_panel;
        let mut view_rect = egui::Rect::NOTHING;
        let out = self
            .egui_ctx
            .run_ui(raw, |ui| view_rect = ui::draw(ui, model, show_panel));
        self.egui_state
            .handle_platform_output(&self.window, out.platform_output);
        // egui's own animations (a spinner, a header opening) ask for the next frame.
        if let Some(v) = out.viewport_output.get(&egui::ViewportId::ROOT) {
            if v.repaint_delay < Duration::from_secs(1) {
                let at = Instant::now() + v.repaint_delay;
                self.egui_repaint_at = Some(self.egui_repaint_at.map_or(at, |t| t.min(at)));
            }
        }
        let ppp = out.pixels_per_point;
        // The volume view: the window less the panel, in whole pixels.
        let rect = self.view_rect_pixels(view_rect, ppp);
        if rect != self.view_rect {
            self.view_rect = rect;
            self.changed();
        }
        let primitives = self.egui_ctx.tessellate(out.shapes, ppp);
        let mut textures = out.textures_delta;
        // Freed after the frame that last drew with them has completed.
        self.pending_free.extend(textures.free.drain());
        for (id, deltas) in textures.set.drain() {
            for delta in &deltas {
                let queue = self.ctx.queue_handle();
                self.gpu
                    .egui_renderer
                    .set_texture(queue, self.gpu.egui_pool.raw, id, delta)
                    .map_err(|e| Error::Invalid(format!("egui's textures: {e}")))?;
            }
        }
        Ok(Some(UiFrame {
            rect,
            ppp,
            primitives,
        }))
    }

    /// Takes the panels' requests and the bench's orbit step, applies the scene's edits to the
    /// GPU state, and decides the frame's quality: the view to render and whether it is the full
    /// (refined) one.
    pub(crate) fn apply_frame(&mut self, ui: &UiFrame) -> Result<(Result<View>, bool)> {
        if self.session.model.requests.screenshot && self.session.screenshot.is_none() {
            self.session.screenshot =
                Some(files::next_screenshot_path(&self.session.screenshot_dir)?);
        }
        self.session.model.requests.screenshot = false;
        let reset = self.session.model.requests.reset_camera;
        self.session.tick_playback(Instant::now());
        self.session.handle_requests(self.view_size());
        if reset {
            self.changed();
        }
        self.session.bench_step();
        self.apply()?;
        let full = self.session.screenshot.is_some()
            || match &self.session.bench {
                Some(b) => b.full,
                None => self.input.last_change.elapsed() >= REFINE_AFTER,
            };
        let view_size = [ui.rect[2], ui.rect[3]];
        let render_size = if full {
            view_size
        } else {
            [view_size[0].div_ceil(2), view_size[1].div_ceil(2)]
        };
        self.session.model.render_size = render_size;
        self.print_layout(ui.rect, ui.ppp);
        self.session.model.interactive = !full;
        let mut view = self.session.model.scene.view(self.session.model.oriented);
        if let Ok(v) = &mut view {
            v.size = render_size;
            // While something moves on a CPU device, lines come from the seeded traversal
            // (Burns et al.'s interactive mode: followed from the previous frame's lines); the
            // refined frame visits every cell. On a GPU every cell is the faster of the two
            // (CT head, both kinds: 0.75 ms against 4.7 ms seeded on an H100, BENCHMARKS.md).
            let seeded_pays = self.ctx.info.device_type == "CPU";
            if let (false, Some(st), true) = (full, &mut v.style, seeded_pays) {
                st.params.line_seeded = true;
            }
            // And one plane per voxel along the longest axis of the finest level read, not the
            // refined frame's two (as VTK's mapper widens its sample distance while the user
            // interacts), when the scene sets no planes; the opacity correction follows the
            // spacing.
            if !full && v.slices.is_none() {
                v.slices = Some(voxel_planes(self.gpu.scene.volume(), v));
            }
        }
        Ok((view.map_err(|e| Error::Invalid(e.to_string())), full))
    }

    /// Acquires a swapchain image and records one frame into it: the renderer's passes (unless
    /// the view and state equal the last rendered frame's, which only presents the persistent
    /// layers again), a readback for a screenshot, the present pass and egui; then presents.
    pub(crate) fn record_and_present(
        &mut self,
        ui: &UiFrame,
        view: Result<View>,
    ) -> Result<Option<Drawn>> {
        let slot = self.gpu.frames.next_slot()?;
        // Bricks that arrived go up with this frame, which then draws anew; a frame never
        // waits for them.
        let loads = match &mut self.gpu.scene {
            Prepared::Paged(p, s) => {
                s.arrivals(&mut p.volume.paged, UPLOADS_PER_FRAME, None, false)?
            }
            Prepared::InCore(_) => Default::default(),
        };
        if loads.placed > 0 {
            self.session.epoch += 1;
        }
        let loads = loads.uploads;
        let Some(image) = self.gpu.swapchain.acquire(slot)? else {
            self.resize = true;
            self.window.request_redraw();
            return Ok(None);
        };
        // What this frame depends on, compared with the last frame's key in place: an orbit
        // changes only the view, and cloning the scene and transfer functions every frame was
        // the viewer's largest per-frame allocation.
        let session = &self.session;
        let same_state = session.last_drawn.as_ref().is_some_and(|k| {
            k.scene == session.applied
                && k.tf == session.applied_tf
                && k.otf == session.applied_otf
                && k.epoch == session.epoch
        });
        let reuse =
            same_state && matches!((&view, &session.last_drawn), (Ok(v), Some(k)) if k.view == *v);
        let key = match &view {
            Ok(_) if reuse => DrawnState::Same,
            Ok(v) if same_state => DrawnState::View(Box::new(v.clone())),
            Ok(v) => DrawnState::All(Box::new(DrawnKey {
                view: v.clone(),
                scene: session.applied.clone(),
                tf: session.applied_tf.clone(),
                otf: session.applied_otf.clone(),
                epoch: session.epoch,
            })),
            Err(_) => DrawnState::None,
        };
        let readback_wanted = self.session.screenshot.is_some();
        let background = self.session.model.scene.background;
        let (mut readback, mut render_error) = (None, None);
        let (ctx, renderer, gpu, targets) = (
            &self.ctx,
            &mut self.gpu.renderer,
            &mut self.gpu.scene,
            &mut self.gpu.targets,
        );
        let pass = PresentPass {
            swapchain: &self.gpu.swapchain,
            present: &self.gpu.present,
            sampler: &self.gpu.sampler,
            ui,
            background,
        };
        let egui_renderer = &mut self.gpu.egui_renderer;
        let (_, index) = self.gpu.frames.frame_sync(|f| {
            if let Prepared::Paged(p, _) = &*gpu {
                vellum_render::render::stream::record_arrivals(&p.volume, ctx, f, &loads)?;
            }
            let (volume, classify) = gpu.parts();
            let drawn = match &view {
                Ok(_) if reuse => Ok(()),
                Ok(v) => renderer.record(f, volume, classify, v, targets).map(|_| ()),
                Err(e) => Err(Error::Invalid(e.to_string())),
            };
            let drawn = drawn.map_err(|e| render_error = Some(e)).is_ok();
            if drawn && readback_wanted {
                let rb = TargetsReadback::new(ctx, targets)?;
                rb.record(f, targets);
                readback = Some(rb);
            }
            let composite = targets.layer("composite").filter(|_| drawn);
            pass.record(ctx, f.cmd, &image, composite, egui_renderer)?;
            Ok((
                (),
                SubmitSync {
                    wait: vec![(
                        image.acquired,
                        vk::PipelineStageFlags2::COLOR_ATTACHMENT_OUTPUT,
                    )],
                    signal: vec![image.rendered],
                },
            ))
        })?;
        if let (Ok(v), false, true) = (&view, reuse, self.gpu.scene.is_paged()) {
            self.gpu.last_view = Some(v.clone());
        }
        if !self.gpu.swapchain.present(&image)? {
            self.resize = true;
        }
        Ok(Some(Drawn {
            index,
            reuse,
            key,
            render_error,
            readback,
            background,
        }))
    }

    /// The frame-rate and GPU figures the corner shows and a bench reports, and egui's textures
    /// freed once no frame draws with them.
    pub(crate) fn timings(&mut self, drawn: &Drawn) -> Result<()> {
        let now = Instant::now();
        // The rate of rendered frames: frames that only presented the last render (idle redraws)
        // would make the renderer look faster than it is.
        if !drawn.reuse {
            if let Some(t) = self.last_rendered.replace(now) {
                let ms = (now - t).as_secs_f64() * 1e3;
                self.session.model.fps = 0.9 * self.session.model.fps + 0.1 * (1e3 / ms.max(1e-3));
            }
            self.timings_of = Some(drawn.index);
        }
        if self.first_frame_ms.is_none() {
            self.first_frame_ms = Some((now - self.opened).as_secs_f64() * 1e3);
        }
        if let Some(t) = self.last_present.replace(now) {
            let ms = (now - t).as_secs_f64() * 1e3;
            if let Some(b) = &mut self.session.bench {
                b.presented(ms);
            }
            if let Some(p) = &mut self.session.pending_occlusion {
                p.frames += 1;
                p.longest_ms = p.longest_ms.max(ms);
            }
        }
        for r in self.gpu.frames.take_finished() {
            if self.timings_of.is_some_and(|i| r.index >= i) {
                self.timings_of = None;
            }
            if let Some(b) = &mut self.session.bench {
                b.completed(&r.passes);
            }
            // A frame that only presented the last render keeps that render's figures.
            if !r.passes.is_empty() {
                set_gpu_ms(&mut self.session.model.gpu_ms, &r.passes);
            }
            self.stream_requests()?;
        }
        if !self.pending_free.is_empty() {
            self.gpu.frames.wait_idle()?;
            for id in std::mem::take(&mut self.pending_free) {
                self.gpu
                    .egui_renderer
                    .free_texture(id)
                    .map_err(|e| Error::Invalid(format!("egui's textures: {e}")))?;
            }
        }
        Ok(())
    }

    /// After a frame completed: what its rays asked for goes to the loaders (coarse levels
    /// first, then nearest the eye), and the corner's line says where the cache stands.
    pub(crate) fn stream_requests(&mut self) -> Result<()> {
        let (Prepared::Paged(p, s), Some(view)) = (&mut self.gpu.scene, &self.gpu.last_view) else {
            self.session.model.streaming = None;
            return Ok(());
        };
        let paged = &mut p.volume.paged;
        let feedback = paged.take_feedback()?;
        if let Some(b) = &mut self.session.bench {
            b.streamed(feedback.wanted.len(), feedback.used.len());
        }
        paged.cache.touch(&feedback.used);
        s.request(paged, view, &feedback.wanted, Order::CoarseFirst);
        self.session.model.streaming = Some(stream_status(s, paged));
        Ok(())
    }

    /// Whether bricks are on their way (the loop keeps drawing until they are up).
    pub(crate) fn streaming(&self) -> bool {
        matches!(&self.gpu.scene, Prepared::Paged(_, s) if s.outstanding() > 0)
    }

    /// What the frame leaves behind: the key of what it rendered, a refused setting rolled back
    /// with its message, and the screenshot written.
    pub(crate) fn finish_frame(&mut self, drawn: Drawn, full: bool) -> Result<()> {
        match (&drawn.render_error, drawn.key, &mut self.session.last_drawn) {
            (Some(_), _, last) | (None, DrawnState::None, last) => *last = None,
            (None, DrawnState::Same, _) => {}
            (None, DrawnState::View(v), Some(last)) => last.view = *v,
            (None, DrawnState::View(_), last) => *last = None,
            (None, DrawnState::All(k), last) => *last = Some(*k),
        }
        match drawn.render_error {
            Some(e) => self.session.refused(&e),
            None if full => self.input.refined = true,
            None => {}
        }
        if let (Some(rb), Some(path)) = (drawn.readback, self.session.screenshot.take()) {
            self.gpu.frames.wait_idle()?;
            let (pixels, _) = rb.read()?;
            let [w, h] = rb.size();
            vellum_volume::output::write_png_rgb(&path, w, h, &to_rgb8(&pixels, drawn.background))?;
            // A bench's report owns standard output (it may be JSON).
            match self.session.bench {
                Some(_) => eprintln!("screenshot: {}", path.display()),
                None => println!("screenshot: {}", path.display()),
            }
            self.session.model.message = format!("wrote {}", path.display());
            // One more frame shows the message.
            self.window.request_redraw();
        }
        Ok(())
    }

    /// With `VELLUM_VIEW_LAYOUT=1`, prints where the volume view and the named widgets
    /// ([`Model::marks`]) are, in window pixels, and the panel's message line, whenever they
    /// change: a hook for tests that drive the panels with real X events.
    pub(crate) fn print_layout(&mut self, view: [u32; 4], ppp: f32) {
        if std::env::var_os("VELLUM_VIEW_LAYOUT").is_none() {
            return;
        }
        let mut line = format!(
            "layout view {} {} {} {}",
            view[0], view[1], view[2], view[3]
        );
        for (name, r) in &self.session.model.marks {
            let [x, y, w, h] =
                [r.min.x, r.min.y, r.width(), r.height()].map(|v| (v * ppp).round() as i64);
            line += &format!(" {name} {x} {y} {w} {h}");
        }
        if line != self.last_layout {
            println!("{line}");
            self.last_layout = line;
        }
        if self.session.model.message != self.last_message {
            println!("message: {}", self.session.model.message);
            self.last_message = self.session.model.message.clone();
        }
    }

    /// The volume view's rectangle (x, y, width, height) in window pixels, at least 1×1 and
    /// inside the swapchain.
    pub(crate) fn view_rect_pixels(&self, r: egui::Rect, ppp: f32) -> [u32; 4] {
        let [w, h] = self.gpu.swapchain.extent;
        if !r.is_positive() || !r.is_finite() {
            return [0, 0, w, h];
        }
        let x0 = ((r.min.x * ppp).round().max(0.0) as u32).min(w - 1);
        let y0 = ((r.min.y * ppp).round().max(0.0) as u32).min(h - 1);
        let x1 = ((r.max.x * ppp).round() as u32).clamp(x0 + 1, w);
        let y1 = ((r.max.y * ppp).round() as u32).clamp(y0 + 1, h);
        [x0, y0, x1 - x0, y1 - y0]
    }

    pub(crate) fn bench_report(&self) -> BenchReport {
        let base = BenchReport {
            device: self.ctx.info.name.clone(),
            input: self.session.model.scene.input.path.clone(),
            size: self.view_size(),
            quality: match self.session.bench.as_ref().is_some_and(|b| b.full) {
                true => "full",
                false => "interactive",
            },
            render_size: self.session.model.render_size,
            frames: 0,
            frames_presented: 0,
            fps: f64::NAN,
            p50_ms: f64::NAN,
            p95_ms: f64::NAN,
            p99_ms: f64::NAN,
            gpu_ms: Vec::new(),
            rss_kib: Vec::new(),
            heap_bytes: Vec::new(),
            first_frame_ms: self.first_frame_ms,
            streaming: self.session.model.streaming.clone(),
            time_points_shown: 0,
            time_points_per_s: None,
            rows: Vec::new(),
        };
        match &self.session.bench {
            Some(b) => b.report(base),
            None => base,
        }
    }
}

/// The corner's pass times from a completed frame's, in place: a frame with the same passes as
/// the last one (every steady frame) allocates nothing.
pub(crate) fn set_gpu_ms(shown: &mut Vec<(String, f64)>, passes: &[vellum_gpu::PassTime]) {
    let same = shown.len() == passes.len() && shown.iter().zip(passes).all(|(s, p)| s.0 == p.name);
    if same {
        for (s, p) in shown.iter_mut().zip(passes) {
            s.1 = p.ms;
        }
    } else {
        *shown = passes.iter().map(|p| (p.name.clone(), p.ms)).collect();
    }
}

/// Bricks uploaded per frame at most, so that a frame stays short while the view refines.
pub const UPLOADS_PER_FRAME: usize = 24;

/// The corner's line of a streamed volume: resident, requested and streamed bricks, and the
/// sentence of bricks that could not be read (drawn from coarser levels instead).
pub(crate) fn stream_status(s: &Streamer, paged: &vellum_render::passes::paging::Paged) -> String {
    let line = format!(
        "bricks {}/{} resident, {} requested, {} streamed ({:.0} MiB)",
        paged.cache.resident(),
        paged.cache.capacity(),
        s.outstanding(),
        s.uploaded,
        s.uploaded_bytes as f64 / (1 << 20) as f64
    );
    match &s.failure {
        Some(f) => format!("{line}; drawn from coarser levels where bricks are missing: {f}"),
        None => line,
    }
}
