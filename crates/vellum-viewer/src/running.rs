//! The window's state coming up and going on: the window, its surface's extensions and egui's
//! renderer, the first volume's GPU state, the pointer's and keyboard's gestures handed to the
//! session, and the session's finished work (a load, an occlusion volume) and edits applied to
//! the GPU state.

use super::*;
use vellum_render::passes::normals::Normals;

/// The window and what Vulkan needs of it: its display and window handles, and the instance
/// extensions presenting to it takes.
pub(crate) fn open_window(
    event_loop: &ActiveEventLoop,
    opts: &ViewOptions,
) -> Result<(
    Arc<Window>,
    winit::raw_window_handle::RawDisplayHandle,
    winit::raw_window_handle::RawWindowHandle,
    Presentation,
)> {
    let attrs = Window::default_attributes()
        .with_title(format!("vellum: {}", opts.scene.input.path))
        .with_inner_size(winit::dpi::PhysicalSize::new(
            opts.window_size[0],
            opts.window_size[1],
        ));
    let window = Arc::new(
        event_loop
            .create_window(attrs)
            .map_err(|e| Error::Invalid(format!("cannot create a window: {e}")))?,
    );
    let display = window
        .display_handle()
        .map_err(|e| Error::Invalid(format!("the window has no display handle: {e}")))?
        .as_raw();
    let handle = window
        .window_handle()
        .map_err(|e| Error::Invalid(format!("the window has no handle: {e}")))?
        .as_raw();
    let present = vellum_gpu::swapchain::presentation(display)?;
    Ok((window, display, handle, present))
}

/// egui's renderer, drawing into the swapchain's format with our device and allocator, and the
/// command pool it uploads its textures through.
pub(crate) fn egui_renderer(
    ctx: &Arc<Context>,
    format: vk::Format,
    in_flight: usize,
) -> Result<(
    egui_ash_renderer::Renderer<egui_ash_renderer::allocator::GpuAllocator>,
    CommandPool,
)> {
    let egui_renderer = egui_ash_renderer::Renderer::with_gpu_allocator(
        ctx.shared_allocator(),
        ctx.device.clone(),
        egui_ash_renderer::RenderMode::DynamicRendering(egui_ash_renderer::DynamicRendering {
            color_attachment_format: format,
            depth_attachment_format: None,
            stencil_attachment_format: None,
        }),
        egui_ash_renderer::Options {
            in_flight_frames: in_flight,
            ..Default::default()
        },
    )
    .map_err(|e| Error::Invalid(format!("egui's renderer: {e}")))?;
    let egui_pool = CommandPool::new(ctx, "egui")?;
    Ok((egui_renderer, egui_pool))
}

/// The pipeline that draws the volume view's image into the swapchain's.
fn present_pipeline(ctx: &Arc<Context>, format: vk::Format) -> Result<GraphicsPipeline> {
    GraphicsPipeline::new(
        ctx,
        &GraphicsDesc {
            name: "present",
            vertex_shader: "render/fullscreen.vert",
            fragment_shader: "viewer/present.frag",
            bindings: &[BindingKind::SampledImage],
            push_constant_bytes: 32,
            vertex_stride: 0,
            color_formats: &[format],
            blend: &[vellum_gpu::graphics::Blend::Replace],
            depth: None,
            fragment_constants: &[],
        },
    )
}

impl Running {
    pub(crate) fn new(event_loop: &ActiveEventLoop, opts: &ViewOptions) -> Result<Self> {
        let (window, display, handle, present) = open_window(event_loop, opts)?;
        let ctx = Context::with_presentation(
            &ContextDesc {
                validation: None,
                device: opts.device.clone(),
            },
            &present,
        )?;
        let opened = Instant::now();
        let budget = Budget {
            gpu: vellum_render::render::bricked::gpu_budget_bytes(&ctx, opts.gpu_budget)?,
            session: SessionOptions::default()
                .with_memory_budget(opts.memory_budget, "--memory-budget")?,
        };
        let mut loaded = session::load(opts.scene.clone(), &budget)?;
        let size = window.inner_size();
        let frames = Frames::new(&ctx, &FramesDesc::interactive("view"))?;
        // SAFETY: the window (held in `Running` after the swapchain) outlives it.
        let swapchain = unsafe {
            Swapchain::new(
                &ctx,
                display,
                handle,
                [size.width.max(1), size.height.max(1)],
                frames.len(),
                opts.vsync,
            )?
        };
        let present = present_pipeline(&ctx, swapchain.format)?;
        let (egui_renderer, egui_pool) = egui_renderer(&ctx, swapchain.format, frames.len())?;
        let egui_ctx = egui::Context::default();
        let egui_state = egui_winit::State::new(
            egui_ctx.clone(),
            egui::ViewportId::ROOT,
            &window,
            Some(window.scale_factor() as f32),
            None,
            Some(ctx.info.max_image_dimension_2d as usize),
        );
        let renderer = Renderer::new(&ctx)?;
        let normals = Normals::new(&ctx)?;
        let mut gpu = prepare_gpu(&normals, &mut loaded, &budget)?;
        let spectrum = gpu.take_spectrum();
        let dims = gpu.volume().dims();
        let (segments, channels) = (segments_of(&mut gpu), channels_of(&mut gpu));
        let mut session = Session::new(
            loaded,
            spectrum,
            dims,
            SessionSetup {
                device: opts.device.clone(),
                device_name: ctx.info.name.clone(),
                screenshot_dir: opts.screenshot_dir.clone(),
                bench: BenchLog::of_view(opts),
                budget: budget.clone(),
                play: opts.play,
                step: crate::timeline::step_of(opts.play_rate),
            },
        );
        session.model.segments = segments;
        session.applied_channels = channels.clone();
        session.model.channels = channels;
        session.fix_channel_scales();
        Ok(Running {
            gpu: GpuState {
                frames,
                egui_renderer,
                egui_pool,
                swapchain,
                present,
                sampler: Sampler::new(&ctx, true)?,
                targets: FrameTargets::new(&ctx),
                renderer,
                scene: gpu,
                last_view: None,
                budget,
                normals,
                ahead: None,
            },
            session,
            input: Input {
                drag: None,
                cursor: [0.0; 2],
                shift: false,
                ctrl: false,
                last_click: None,
                pressed_at: None,
                last_change: Instant::now() - REFINE_AFTER,
                refined: false,
            },
            egui_ctx,
            egui_state,
            resize: false,
            pending_free: Vec::new(),
            view_rect: [0; 4],
            show_panel: opts.bench_frames.is_none(),
            last_layout: String::new(),
            last_message: String::new(),
            last_present: None,
            last_rendered: None,
            timings_of: None,
            egui_repaint_at: None,
            errors_in_a_row: 0,
            opened,
            first_frame_ms: None,
            window,
            ctx,
        })
    }

    /// A mouse button pressed over the view: left orbits (with shift, pans), right and middle
    /// pan; a second left click within 350 ms resets the camera.
    pub(crate) fn press(&mut self, button: MouseButton) {
        let kind = match button {
            MouseButton::Left if self.input.shift => Some(Drag::Pan),
            MouseButton::Left => Some(Drag::Orbit),
            MouseButton::Right | MouseButton::Middle => Some(Drag::Pan),
            _ => None,
        };
        if button == MouseButton::Left {
            let now = Instant::now();
            if self
                .input
                .last_click
                .is_some_and(|t| now - t < Duration::from_millis(350))
            {
                self.reset_camera();
            }
            self.input.last_click = Some(now);
            self.input.pressed_at = Some(self.input.cursor);
        }
        self.input.drag = kind.map(|k| (k, self.input.cursor));
    }

    /// A mouse button released over the view: a left click that did not move (within 3 pixels)
    /// picks the segment under the pointer, when the volume has segments.
    pub(crate) fn release(&mut self, button: MouseButton) {
        self.input.drag = None;
        let pressed = self.input.pressed_at.take();
        let [x, y] = self.input.cursor;
        let still = pressed.is_some_and(|p| (p[0] - x).hypot(p[1] - y) <= 3.0);
        if button == MouseButton::Left && still && self.session.model.segments.is_some() {
            self.pick([x, y]);
        }
    }

    /// Picks the segment at window position `p` (pixels) with [`vellum_render::render::pick`],
    /// and says which in the message line and the segments panel.
    fn pick(&mut self, p: [f64; 2]) {
        let Ok(mut view) = self.session.model.scene.view(self.session.model.oriented) else {
            return;
        };
        view.size = self.view_size();
        let [vx, vy, ..] = self.view_rect;
        let pixel = [(p[0] - vx as f64) as f32, (p[1] - vy as f64) as f32];
        let range = self.gpu.scene.volume().range();
        let Some(gpu) = self.gpu.scene.classify().labels.as_ref() else {
            return;
        };
        let input = vellum_render::render::pick::PickInput {
            volume: &self.session.volume,
            range,
            tf: &self.session.applied_tf,
            labels: &gpu.labels,
            spec: gpu.spec(),
            background: gpu.background(),
        };
        let picked = vellum_render::render::pick::pick_label(&input, &view, pixel);
        let m = &mut self.session.model;
        if let Some(list) = m.segments.as_mut() {
            list.picked = picked;
            m.message = match picked {
                Some(id) => format!("picked label {id} ({} voxels)", list.count_of(id)),
                None => "no segment under the pointer".into(),
            };
        }
        self.changed();
    }

    /// A key pressed outside egui: the session's keys, and the panel's.
    pub(crate) fn key(&mut self, key: &Key) {
        let press = match key {
            Key::Named(NamedKey::Escape) => KeyPress::Escape,
            Key::Character(c) => KeyPress::Char(c.to_string()),
            _ => return,
        };
        if self.session.key(&press, self.input.ctrl) {
            self.show_panel = !self.show_panel;
            self.changed();
        }
    }

    /// Something changed: render at reduced resolution until [`REFINE_AFTER`] has passed.
    pub(crate) fn changed(&mut self) {
        self.input.last_change = Instant::now();
        self.input.refined = false;
        self.window.request_redraw();
    }

    /// Whether a window position (pixels) lies in the volume view.
    pub(crate) fn in_view(&self, p: [f64; 2]) -> bool {
        let [x, y, w, h] = self.view_rect.map(f64::from);
        w == 0.0 || (p[0] >= x && p[0] < x + w && p[1] >= y && p[1] < y + h)
    }

    /// The volume view's size in pixels.
    pub(crate) fn view_size(&self) -> [u32; 2] {
        match self.view_rect {
            [_, _, 0, _] | [_, _, _, 0] => self.gpu.swapchain.extent,
            [_, _, w, h] => [w, h],
        }
    }

    /// The camera as resolved for the current volume and window (the fitted distance filled in).
    pub(crate) fn resolved_camera(&self) -> Result<vellum_render::render::camera::Camera> {
        let mut view = self.session.model.scene.view(self.session.model.oriented)?;
        view.size = self.view_size();
        Ok(frame_camera(&WorldBox::of(self.gpu.scene.volume()), &view))
    }

    pub(crate) fn camera_drag(&mut self, kind: Drag, d: [f64; 2]) {
        let Ok(cam) = self.resolved_camera() else {
            return;
        };
        let view_h = self.view_size()[1];
        self.session.drag(&cam, kind, d, view_h);
        self.changed();
    }

    pub(crate) fn zoom(&mut self, steps: f64) {
        let Ok(cam) = self.resolved_camera() else {
            return;
        };
        self.session.zoom(&cam, steps);
        self.changed();
    }

    pub(crate) fn reset_camera(&mut self) {
        self.session.reset_camera();
        self.changed();
    }

    /// Takes a finished load: the new volume goes to the GPU and replaces the old one. A failed
    /// load keeps the old volume and says why.
    pub(crate) fn poll_load(&mut self) {
        let Some((what, got)) = self.session.take_load() else {
            return;
        };
        let result = got.and_then(|mut l| {
            let gpu = prepare_gpu(&self.gpu.normals, &mut l, &self.gpu.budget)?;
            Ok((l, gpu))
        });
        // Whatever was read ahead belongs to the volume this load replaces.
        self.gpu.ahead = None;
        self.session.ready = None;
        match result {
            Ok((l, gpu)) => self.install(l, gpu, &what),
            Err(e) => self.session.model.message = format!("{what}: {e}"),
        }
        self.changed();
    }

    /// `l` on the GPU as `gpu` in place of the volume shown.
    fn install(&mut self, l: Loaded, mut gpu: Prepared, what: &str) {
        // The old loaders and pools go with the old volume.
        self.gpu.frames.wait_idle().ok();
        let spectrum = gpu.take_spectrum();
        let dims = gpu.volume().dims();
        let (segments, channels) = (segments_of(&mut gpu), channels_of(&mut gpu));
        // Another time point of the series shown: its channels keep the rows' look, which the
        // next apply sends to the new GPU state where it differs from what that loaded.
        let applied = &self.session.applied.input;
        let step = l.scene.input.path == applied.path && l.scene.input.time != applied.time;
        let before = step.then(|| self.session.model.channels.take()).flatten();
        self.gpu.scene = gpu;
        self.session.opened(l, what, spectrum, dims);
        self.session.model.segments = segments;
        self.session.applied_channels = channels.clone();
        self.session.model.channels = match (before, channels) {
            (Some(old), Some(new)) => Some(crate::ui::ChannelRow::carried(&old, new)),
            (_, new) => new,
        };
        self.session.fix_channel_scales();
        self.window
            .set_title(&format!("vellum: {}", self.session.model.scene.input.path));
    }

    /// While a series plays: the time point read ahead goes on the GPU as soon as it is read
    /// (in its own textures, beside the ones drawn), so that its turn only swaps them; and the
    /// session's turn to show it does so.
    pub(crate) fn poll_ahead(&mut self) {
        if self.gpu.ahead.is_none() && self.session.playing() {
            if let Some((t, got)) = self.session.take_prefetched() {
                // The one after it is read while this one goes on the GPU.
                if got.is_ok() {
                    self.session.prefetch_after(t);
                }
                let result = got.and_then(|mut l| {
                    let gpu = prepare_gpu(&self.gpu.normals, &mut l, &self.gpu.budget)?;
                    Ok((l, gpu))
                });
                match result {
                    Ok((l, gpu)) => {
                        self.gpu.ahead = Some((format!("time point {t}"), l, gpu));
                        self.session.ready = Some(t);
                    }
                    Err(e) => {
                        self.session.model.message = format!("time point {t}: {e}");
                        self.session.model.playing = false;
                    }
                }
            }
        }
        if std::mem::take(&mut self.session.swap) {
            if let Some((what, l, gpu)) = self.gpu.ahead.take() {
                self.session.ready = None;
                self.install(l, gpu, &what);
                self.changed();
            }
        }
    }

    /// Takes a finished occlusion volume: it replaces the one the renderer samples, and its
    /// spectrum the editor's.
    pub(crate) fn poll_occlusion(&mut self) {
        let Some((p, got)) = self.session.take_occlusion() else {
            return;
        };
        let attached = got.and_then(|out| {
            let image = vellum_render::passes::volume_image::create(
                &self.ctx,
                "occlusion",
                &out.occlusion,
            )?;
            vellum_gpu::transfer::upload(
                &self.ctx,
                &image,
                out.occlusion.data.as_bytes(),
                Access::FragmentSampled,
            )?;
            Ok((image, out.spectrum))
        });
        match attached {
            Ok((image, spectrum)) => {
                // The old image may be in use by frames in flight: its release is deferred.
                if let Prepared::InCore(g) = &mut self.gpu.scene {
                    g.volume.occlusion = Some(image);
                }
                self.session.occlusion_attached(&p, spectrum);
            }
            Err(e) => self.session.model.message = format!("recomputing the occlusion: {e}"),
        }
        self.changed();
    }

    /// Applies the scene's edits (the session's [`Edit`]s) to the GPU state.
    pub(crate) fn apply(&mut self) -> Result<()> {
        let volume = self.gpu.scene.volume();
        let (range, has_importance) = (volume.range(), volume.importance().is_some());
        for edit in self.session.apply(range, has_importance) {
            let classify = self.gpu.scene.classify();
            match edit {
                Edit::Focus(f) => classify.focus = f,
                Edit::Transfer(tf) => classify.set_transfer(&tf),
                Edit::OcclusionTable(table) => classify.set_occlusion_table(Some(table))?,
                Edit::Modulation(m) => classify.modulation = m,
                Edit::Labels(spec) => {
                    if let Some(l) = classify.labels.as_mut() {
                        l.set_spec(&spec)?;
                    }
                }
                Edit::Channels(tfs) => {
                    if let Some(c) = classify.channels.as_mut() {
                        c.set_tfs(&tfs)?;
                    }
                }
            }
        }
        Ok(())
    }
}

/// The segments panel's list of the label volume `gpu` draws, if it has one.
fn segments_of(gpu: &mut Prepared) -> Option<crate::ui::Segments> {
    let l = gpu.classify().labels.as_ref()?;
    Some(crate::ui::Segments::of(&l.labels, l.background()))
}

/// The channel list of the channels `gpu` mixes, if it mixes several.
fn channels_of(gpu: &mut Prepared) -> Option<Vec<crate::ui::ChannelRow>> {
    let c = gpu.classify().channels.as_ref()?;
    Some(c.info.iter().map(crate::ui::ChannelRow::of).collect())
}

/// The GPU state of a loaded volume: in core (with its gradients stored, or made at each sample
/// where only its intensity fits the budget, the scene then made to ray-cast it), or the brick
/// cache's pools with the streamer started on the coarsest level (and the scene made to
/// ray-cast it).
pub(crate) fn prepare_gpu(normals: &Normals, l: &mut Loaded, budget: &Budget) -> Result<Prepared> {
    let ctx = normals.context();
    let Some(levels) = l.levels.take() else {
        // `auto` was windowed on the worker already, over the range the textures take: not again
        // here, on the thread that draws.
        let classification = match &l.classification {
            vellum_render::classify::Classification::Auto => {
                vellum_render::classify::Classification::Transfer(l.tf.clone())
            }
            c => c.clone(),
        };
        use vellum_render::render::session::{gradient_source, ray_cast_only, RayCastOnly};
        let source = gradient_source(&l.scene, l.volume.dims, budget.gpu);
        let input = (&l.volume, l.scene.input.scale(), source);
        let mut prepared = Prepared::in_core(normals, input, &l.scene, &classification)?;
        // Segments of a label volume and mixed channels, as `render` draws them.
        vellum_render::render::session::attach_beside(ctx, &l.scene, &mut prepared)?;
        // The session's rule: the ray caster draws a volume whose gradients are made at each
        // sample.
        if source == vellum_render::passes::normals::GradientSource::AtSample {
            let why = RayCastOnly::GradientsAtSample;
            if let Some(said) = ray_cast_only(&mut l.scene.raycast, budget.gpu, why) {
                log::info!("{said}");
            }
        }
        return Ok(prepared);
    };
    let opened = Opened::Bricked(levels);
    let opts = (budget.gpu, &budget.session);
    let mut prepared = Prepared::new(ctx, &l.scene, &l.classification, &opened, opts)?;
    // Segments of a label volume and mixed channels: their bricks carry them.
    vellum_render::render::session::attach_beside(ctx, &l.scene, &mut prepared)?;
    // The session's rule: the ray caster draws bricked volumes.
    use vellum_render::render::session::{ray_cast_only, RayCastOnly};
    let said = ray_cast_only(&mut l.scene.raycast, budget.gpu, RayCastOnly::Bricked);
    if let Some(said) = said {
        log::info!("{said}");
    }
    Ok(prepared)
}
