//! `vellum view`: the windowed viewer. A winit window, a swapchain, our renderer drawing the
//! volume into its persistent layers, a present pass that lays the composite over the background
//! into the swapchain image, and egui's panels over it, all in one frame of a two-slot ring
//! (`gpu::Frames`): the CPU records frame N+1 while the GPU runs frame N.
//!
//! The viewer edits a [`Scene`], the structure `vellum render --scene` reads. A saved scene
//! renders from the command line to the image the window shows (a test compares them), so the
//! viewer and the CLI are one renderer.
//!
//! Adaptive quality: while the camera moves or a control is dragged, frames render at half the
//! window's resolution and the present pass scales them up; [`REFINE_AFTER`] after the last
//! change, one frame at full resolution follows and the loop goes idle until the next event.

mod bench;
mod session;
pub mod swapchain;
mod ui;

use crate::swapchain::Swapchain;
use ash::vk;
use bench::BenchLog;
pub use bench::BenchReport;
use session::{Drag, DrawnKey, Edit, KeyPress, Loaded, Session, SessionSetup};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};
use vellum_error::{Error, Result};
use vellum_gpu::graphics::{begin_rendering_view, end_rendering, GraphicsDesc, GraphicsPipeline};
use vellum_gpu::{
    Access, Bind, BindingKind, Context, ContextDesc, Frames, FramesDesc, Presentation, Sampler,
    SubmitSync,
};
use vellum_render::render::frame::Renderer;
use vellum_render::render::scene::{GpuScene, Scene};
use vellum_render::render::session::{Opened, Prepared, SessionOptions};
use vellum_render::render::stream::{Order, Streamer};
use vellum_render::render::targets::to_rgb8;
use vellum_render::render::targets::{FrameTargets, TargetsReadback};
use vellum_render::render::view::{frame_camera, View, WorldBox};
use winit::application::ApplicationHandler;
use winit::event::{ElementState, MouseButton, MouseScrollDelta, WindowEvent};
use winit::event_loop::{ActiveEventLoop, ControlFlow, EventLoop};
use winit::keyboard::{Key, NamedKey};
use winit::raw_window_handle::{HasDisplayHandle, HasWindowHandle};
use winit::window::{Window, WindowId};

/// How long after the last change frames stay at reduced resolution.
pub const REFINE_AFTER: Duration = Duration::from_millis(200);

/// What `vellum view` was asked to do.
#[derive(Clone, Debug)]
pub struct ViewOptions {
    /// The scene to open (its input, classification, focus, camera, style...).
    pub scene: Scene,
    /// Device selector (index or name), as `--device`.
    pub device: Option<String>,
    /// Window size in pixels.
    pub window_size: [u32; 2],
    /// Where screenshots (key S) go.
    pub screenshot_dir: PathBuf,
    /// A screenshot written when the window closes.
    pub screenshot_on_exit: Option<PathBuf>,
    /// Present with vsync (FIFO); off picks MAILBOX or IMMEDIATE where offered.
    pub vsync: bool,
    /// Orbit this many frames, report the frame times, and close.
    pub bench_frames: Option<u32>,
    /// Orbit at full resolution; otherwise at the interactive resolution of a drag.
    pub bench_full: bool,
    /// GPU memory for the volume's textures in MiB; a store that needs more is streamed through
    /// the brick cache (default: half the device's largest heap).
    pub gpu_budget: Option<f64>,
}

/// Opens the window and runs until it is closed. Returns the bench report in bench mode.
pub fn run(opts: ViewOptions) -> Result<Option<BenchReport>> {
    let event_loop =
        EventLoop::new().map_err(|e| Error::Invalid(format!("cannot open a window: {e}")))?;
    let mut app = App {
        opts,
        running: None,
        error: None,
        report: None,
    };
    event_loop
        .run_app(&mut app)
        .map_err(|e| Error::Invalid(format!("the window's event loop failed: {e}")))?;
    if let Some(r) = &app.running {
        r.ctx.report_validation();
    }
    drop(app.running.take());
    match app.error {
        Some(e) => Err(e),
        None => Ok(app.report),
    }
}

struct App {
    opts: ViewOptions,
    running: Option<Running>,
    /// An error that ended the viewer (before the window could show it).
    error: Option<Error>,
    report: Option<BenchReport>,
}

/// What egui made of one frame: the volume view's rectangle in pixels (x, y, w, h), the
/// scale, and the triangles to draw.
struct UiFrame {
    rect: [u32; 4],
    ppp: f32,
    primitives: Vec<egui::ClippedPrimitive>,
}

/// What one recorded and presented frame leaves for the steps after it.
struct Drawn {
    /// The frame's number in the ring.
    index: u64,
    /// Whether it only presented the last render again.
    reuse: bool,
    key: DrawnState,
    render_error: Option<Error>,
    readback: Option<TargetsReadback>,
    background: [f32; 3],
}

/// The present pass: the composite over the background in the view's rectangle of the
/// swapchain image, then egui's panels over everything.
struct PresentPass<'a> {
    swapchain: &'a Swapchain,
    present: &'a GraphicsPipeline,
    sampler: &'a Sampler,
    ui: &'a UiFrame,
    background: [f32; 3],
}

impl PresentPass<'_> {
    fn record(
        &self,
        ctx: &Context,
        cmd: vk::CommandBuffer,
        image: &crate::swapchain::Acquired,
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
            let scissor = vk::Rect2D {
                offset: vk::Offset2D {
                    x: rect[0] as i32,
                    y: rect[1] as i32,
                },
                extent: vk::Extent2D {
                    width: rect[2],
                    height: rect[3],
                },
            };
            unsafe {
                ctx.device.cmd_set_scissor(cmd, 0, &[scissor]);
                ctx.device.cmd_draw(cmd, 3, 1, 0, 0);
            }
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

/// How a rendered frame's key differs from the last one's (see `Running::last_drawn`).
enum DrawnState {
    /// No view: nothing is remembered.
    None,
    /// The same key.
    Same,
    /// The same but for the view.
    View(Box<vellum_render::render::view::View>),
    /// A new key.
    All(Box<DrawnKey>),
}

/// The GPU state of a loaded volume: in core, or the brick cache's pools with the streamer
/// started on the coarsest level (and the scene made to ray-cast it).
fn prepare_gpu(ctx: &Arc<Context>, l: &mut Loaded, budget: u64) -> Result<Prepared> {
    let modulation = l.scene.modulation.clone().unwrap_or_default();
    let Some(levels) = l.levels.take() else {
        let gpu = GpuScene::prepare(
            ctx,
            &l.volume,
            &l.classification,
            l.scene.focus,
            &modulation,
        )?;
        return Ok(Prepared::InCore(gpu));
    };
    let opts = SessionOptions::default();
    let opened = Opened::Bricked(levels);
    let prepared = Prepared::new(ctx, &l.scene, &l.classification, &opened, (budget, &opts))?;
    // The ray caster draws bricked volumes.
    if l.scene.raycast.is_none() {
        l.scene.raycast = Some(Default::default());
    }
    Ok(prepared)
}

/// Bricks uploaded per frame at most, so that a frame stays short while the view refines.
pub const UPLOADS_PER_FRAME: usize = 24;

/// The corner's line of a streamed volume: resident, requested and streamed bricks, and the
/// sentence of bricks that could not be read (drawn from coarser levels instead).
fn stream_status(s: &Streamer, paged: &vellum_render::passes::paging::Paged) -> String {
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

/// Everything that exists while the window is open: the GPU state, the session and the input,
/// then egui's and the window's. Field order is drop order: the GPU state first, the window and
/// the context last.
struct Running {
    gpu: GpuState,
    session: Session,
    input: Input,
    egui_ctx: egui::Context,
    egui_state: egui_winit::State,
    resize: bool,
    pending_free: Vec<egui::TextureId>,
    /// The volume view in window pixels (x, y, width, height): the window less the panel.
    view_rect: [u32; 4],
    show_panel: bool,
    last_layout: String,
    last_message: String,
    last_present: Option<Instant>,
    last_rendered: Option<Instant>,
    /// The index of the last rendered frame while its GPU timings are still to be shown: the
    /// loop draws once more when they arrive, so the corner never shows a stale figure.
    timings_of: Option<u64>,
    /// When egui asked to draw again (its animations).
    egui_repaint_at: Option<Instant>,
    errors_in_a_row: u32,
    /// When the window's context was made, and how long after it the first frame was presented.
    opened: Instant,
    first_frame_ms: Option<f64>,
    window: Arc<Window>,
    ctx: Arc<Context>,
}

/// The window's GPU state, in drop order: the frame ring first (it waits for the GPU), egui's
/// renderer before the context whose allocator it shares, the swapchain before the window.
struct GpuState {
    frames: Frames,
    egui_renderer: egui_ash_renderer::Renderer<egui_ash_renderer::allocator::GpuAllocator>,
    egui_pool: CommandPool,
    swapchain: Swapchain,
    present: GraphicsPipeline,
    sampler: Sampler,
    targets: FrameTargets,
    renderer: Renderer,
    /// The volume and its classification on the GPU (with the streamer of a volume in the brick
    /// cache).
    scene: Prepared,
    /// The view of the last frame drawn, whose eye orders the bricks its rays asked for.
    last_view: Option<View>,
    /// GPU memory for a volume's textures; a store that needs more is streamed.
    budget: u64,
}

/// The pointer and keyboard: a drag in progress, modifiers, the last click (for the double
/// click that resets the camera), and when the view last changed (for adaptive quality).
struct Input {
    drag: Option<(Drag, [f64; 2])>,
    cursor: [f64; 2],
    shift: bool,
    ctrl: bool,
    last_click: Option<Instant>,
    last_change: Instant,
    /// Whether the full-resolution frame has been drawn since the last change.
    refined: bool,
}

/// egui uploads its textures through a command pool of its own.
struct CommandPool {
    ctx: Arc<Context>,
    raw: vk::CommandPool,
}

impl Drop for CommandPool {
    fn drop(&mut self) {
        unsafe {
            let _ = self.ctx.device.device_wait_idle();
            self.ctx.device.destroy_command_pool(self.raw, None);
        }
    }
}

impl ApplicationHandler for App {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.running.is_some() {
            return;
        }
        match Running::new(event_loop, &self.opts) {
            Ok(r) => self.running = Some(r),
            Err(e) => {
                self.error = Some(e);
                event_loop.exit();
            }
        }
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        let Some(r) = self.running.as_mut() else {
            return;
        };
        let response = r.egui_state.on_window_event(&r.window, &event);
        // egui asks for a repaint after every event, a redraw included: honouring that one would
        // redraw for ever.
        if response.repaint && !matches!(event, WindowEvent::RedrawRequested) {
            r.window.request_redraw();
        }
        match event {
            WindowEvent::CloseRequested => self.close(event_loop),
            WindowEvent::Resized(_) => {
                r.resize = true;
                r.changed();
            }
            WindowEvent::DroppedFile(path) => {
                r.session
                    .start_load_input(path.to_string_lossy().into_owned());
                r.changed();
            }
            WindowEvent::ModifiersChanged(m) => {
                r.input.shift = m.state().shift_key();
                r.input.ctrl = m.state().control_key();
            }
            WindowEvent::CursorMoved { position, .. } => {
                let p = [position.x, position.y];
                if let Some((kind, last)) = r.input.drag {
                    r.camera_drag(kind, [p[0] - last[0], p[1] - last[1]]);
                    r.input.drag = Some((kind, p));
                }
                r.input.cursor = p;
            }
            // egui judges "over a panel" from its last frame, which lags when frames are slow;
            // the view's rectangle is known here, so a press outside it never moves the camera.
            WindowEvent::MouseInput { state, button, .. }
                if !response.consumed && r.in_view(r.input.cursor) =>
            {
                match state {
                    ElementState::Pressed => r.press(button),
                    ElementState::Released => r.input.drag = None,
                }
            }
            WindowEvent::MouseInput {
                state: ElementState::Released,
                ..
            } => r.input.drag = None,
            WindowEvent::MouseWheel { delta, .. }
                if !response.consumed && r.in_view(r.input.cursor) =>
            {
                let steps = match delta {
                    MouseScrollDelta::LineDelta(_, y) => y as f64,
                    MouseScrollDelta::PixelDelta(p) => p.y / 40.0,
                };
                r.zoom(steps);
            }
            WindowEvent::KeyboardInput { event, .. }
                if !response.consumed && event.state == ElementState::Pressed =>
            {
                r.key(&event.logical_key);
                r.window.request_redraw();
            }
            WindowEvent::RedrawRequested => {
                if let Err(e) = r.redraw() {
                    r.errors_in_a_row += 1;
                    log::error!("{e}");
                    r.session.model.message = e.to_string();
                    // The device is gone or keeps failing: say so and stop, with the sentence.
                    if r.errors_in_a_row >= 3 {
                        self.error = Some(e);
                        event_loop.exit();
                        return;
                    }
                    r.window.request_redraw();
                } else {
                    r.errors_in_a_row = 0;
                }
                if r.session.model.requests.quit {
                    self.close(event_loop);
                    return;
                }
                if let Some(r) = self.running.as_mut() {
                    if r.session.bench.as_ref().is_some_and(|b| b.left == 0) {
                        self.report = Some(r.bench_report());
                        // With --screenshot-on-exit, the last view is written too.
                        self.close(event_loop);
                    }
                }
            }
            _ => {}
        }
    }

    fn about_to_wait(&mut self, event_loop: &ActiveEventLoop) {
        let Some(r) = self.running.as_mut() else {
            return;
        };
        r.poll_load();
        r.poll_occlusion();
        let timings_pending = r.timings_of.is_some();
        if timings_pending && r.gpu.frames.poll().is_ok() && r.gpu.frames.has_finished() {
            r.window.request_redraw();
        }
        let egui_at = r.egui_repaint_at;
        if egui_at.is_some_and(|t| t <= Instant::now()) {
            r.egui_repaint_at = None;
            r.window.request_redraw();
        }
        if r.session.edited() {
            r.changed();
        }
        let busy = r.session.bench.is_some()
            || r.streaming()
            || r.session.loading()
            || r.session.pending_occlusion.is_some();
        let refine_at = r.input.last_change + REFINE_AFTER;
        if busy
            || r.session.model.requests.screenshot
            || Instant::now() < refine_at
            || !r.input.refined
        {
            r.window.request_redraw();
        }
        if Instant::now() < refine_at {
            event_loop.set_control_flow(ControlFlow::WaitUntil(refine_at));
        } else if busy {
            event_loop.set_control_flow(ControlFlow::Poll);
        } else {
            // Wake for the last rendered frame's timings (still on the GPU), or for egui.
            let timings_at = timings_pending.then(|| Instant::now() + Duration::from_millis(20));
            match [timings_at, r.egui_repaint_at].into_iter().flatten().min() {
                Some(at) => event_loop.set_control_flow(ControlFlow::WaitUntil(at)),
                None => event_loop.set_control_flow(ControlFlow::Wait),
            }
        }
    }
}

impl App {
    /// Closes the window, first writing the exit screenshot when one was asked for.
    fn close(&mut self, event_loop: &ActiveEventLoop) {
        if let (Some(r), Some(path)) = (self.running.as_mut(), self.opts.screenshot_on_exit.clone())
        {
            r.session.screenshot = Some(path);
            if let Err(e) = r.redraw() {
                self.error = Some(e);
            }
        }
        event_loop.exit();
    }
}

/// The window and what Vulkan needs of it: its display and window handles, and the instance
/// extensions presenting to it takes.
fn open_window(
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
    let exts = ash_window::enumerate_required_extensions(display)
        .map_err(|e| Error::Invalid(format!("no Vulkan surface for this display: {e}")))?;
    let present = Presentation {
        instance_extensions: exts
            .iter()
            // SAFETY: ash-window returns pointers to static NUL-terminated extension names.
            .map(|&p| unsafe { std::ffi::CStr::from_ptr(p) })
            .collect(),
        swapchain: true,
    };
    Ok((window, display, handle, present))
}

/// egui's renderer, drawing into the swapchain's format with our device and allocator, and the
/// command pool it uploads its textures through.
fn egui_renderer(
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
    let pool_info = vk::CommandPoolCreateInfo::default()
        .queue_family_index(ctx.queue_family)
        .flags(vk::CommandPoolCreateFlags::RESET_COMMAND_BUFFER);
    let egui_pool = CommandPool {
        ctx: ctx.clone(),
        raw: unsafe { ctx.device.create_command_pool(&pool_info, None) }
            .map_err(|e| Error::Invalid(format!("creating egui's command pool: {e}")))?,
    };
    Ok((egui_renderer, egui_pool))
}

impl Running {
    fn new(event_loop: &ActiveEventLoop, opts: &ViewOptions) -> Result<Self> {
        let (window, display, handle, present) = open_window(event_loop, opts)?;
        let ctx = Context::with_presentation(
            &ContextDesc {
                validation: None,
                device: opts.device.clone(),
            },
            &present,
        )?;
        let opened = Instant::now();
        let budget = vellum_render::render::bricked::gpu_budget_bytes(&ctx, opts.gpu_budget)?;
        let mut loaded = session::load(opts.scene.clone(), budget)?;
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
        let present = GraphicsPipeline::new(
            &ctx,
            &GraphicsDesc {
                name: "present",
                vertex_shader: "render/fullscreen.vert",
                fragment_shader: "viewer/present.frag",
                bindings: &[BindingKind::SampledImage],
                push_constant_bytes: 32,
                vertex_stride: 0,
                color_formats: &[swapchain.format],
                blend: &[vellum_gpu::graphics::Blend::Replace],
                depth: None,
                fragment_constants: &[],
            },
        )?;
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
        let mut gpu = prepare_gpu(&ctx, &mut loaded, budget)?;
        let spectrum = match &mut gpu {
            Prepared::InCore(g) => g.spectrum.take(),
            Prepared::Paged(..) => None,
        };
        let dims = gpu.volume().dims();
        let session = Session::new(
            loaded,
            spectrum,
            dims,
            SessionSetup {
                device: opts.device.clone(),
                device_name: ctx.info.name.clone(),
                screenshot_dir: opts.screenshot_dir.clone(),
                bench: opts.bench_frames.map(|n| BenchLog::new(n, opts.bench_full)),
                budget,
            },
        );
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
            },
            session,
            input: Input {
                drag: None,
                cursor: [0.0; 2],
                shift: false,
                ctrl: false,
                last_click: None,
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
    fn press(&mut self, button: MouseButton) {
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
        }
        self.input.drag = kind.map(|k| (k, self.input.cursor));
    }

    /// A key pressed outside egui: the session's keys, and the panel's.
    fn key(&mut self, key: &Key) {
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
    fn changed(&mut self) {
        self.input.last_change = Instant::now();
        self.input.refined = false;
        self.window.request_redraw();
    }

    /// Whether a window position (pixels) lies in the volume view.
    fn in_view(&self, p: [f64; 2]) -> bool {
        let [x, y, w, h] = self.view_rect.map(f64::from);
        w == 0.0 || (p[0] >= x && p[0] < x + w && p[1] >= y && p[1] < y + h)
    }

    /// The volume view's size in pixels.
    fn view_size(&self) -> [u32; 2] {
        match self.view_rect {
            [_, _, 0, _] | [_, _, _, 0] => self.gpu.swapchain.extent,
            [_, _, w, h] => [w, h],
        }
    }

    /// The camera as resolved for the current volume and window (the fitted distance filled in).
    fn resolved_camera(&self) -> Result<vellum_render::render::camera::Camera> {
        let mut view = self.session.model.scene.view(self.session.model.oriented)?;
        view.size = self.view_size();
        Ok(frame_camera(&WorldBox::of(self.gpu.scene.volume()), &view))
    }

    fn camera_drag(&mut self, kind: Drag, d: [f64; 2]) {
        let Ok(cam) = self.resolved_camera() else {
            return;
        };
        let view_h = self.view_size()[1];
        self.session.drag(&cam, kind, d, view_h);
        self.changed();
    }

    fn zoom(&mut self, steps: f64) {
        let Ok(cam) = self.resolved_camera() else {
            return;
        };
        self.session.zoom(&cam, steps);
        self.changed();
    }

    fn reset_camera(&mut self) {
        self.session.reset_camera();
        self.changed();
    }

    /// Takes a finished load: the new volume goes to the GPU and replaces the old one. A failed
    /// load keeps the old volume and says why.
    fn poll_load(&mut self) {
        let Some((what, got)) = self.session.take_load() else {
            return;
        };
        let budget = self.gpu.budget;
        let result = got.and_then(|mut l| {
            let gpu = prepare_gpu(&self.ctx, &mut l, budget)?;
            Ok((l, gpu))
        });
        match result {
            Ok((l, mut gpu)) => {
                // The old loaders and pools go with the old volume.
                self.gpu.frames.wait_idle().ok();
                let spectrum = match &mut gpu {
                    Prepared::InCore(g) => g.spectrum.take(),
                    Prepared::Paged(..) => None,
                };
                let dims = gpu.volume().dims();
                self.gpu.scene = gpu;
                self.session.opened(l, &what, spectrum, dims);
                self.window
                    .set_title(&format!("vellum: {}", self.session.model.scene.input.path));
            }
            Err(e) => self.session.model.message = format!("{what}: {e}"),
        }
        self.changed();
    }

    /// Takes a finished occlusion volume: it replaces the one the renderer samples, and its
    /// spectrum the editor's.
    fn poll_occlusion(&mut self) {
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
    fn apply(&mut self) -> Result<()> {
        let volume = self.gpu.scene.volume();
        let (range, has_importance) = (volume.range(), volume.importance().is_some());
        for edit in self.session.apply(range, has_importance) {
            let classify = self.gpu.scene.classify();
            match edit {
                Edit::Focus(f) => classify.focus = f,
                Edit::Transfer(tf) => classify.set_transfer(&tf),
                Edit::OcclusionTable(table) => classify.set_occlusion_table(Some(table))?,
                Edit::Modulation(m) => classify.modulation = m,
            }
        }
        Ok(())
    }

    /// Renders and presents one frame (with a screenshot's readback when one is pending).
    /// One window frame: ui → apply → record → present → timings.
    fn redraw(&mut self) -> Result<()> {
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
    fn run_ui(&mut self) -> Result<Option<UiFrame>> {
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
    fn apply_frame(&mut self, ui: &UiFrame) -> Result<(Result<View>, bool)> {
        if self.session.model.requests.screenshot && self.session.screenshot.is_none() {
            self.session.screenshot =
                Some(session::next_screenshot_path(&self.session.screenshot_dir)?);
        }
        self.session.model.requests.screenshot = false;
        let reset = self.session.model.requests.reset_camera;
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
        }
        Ok((view.map_err(|e| Error::Invalid(e.to_string())), full))
    }

    /// Acquires a swapchain image and records one frame into it: the renderer's passes (unless
    /// the view and state equal the last rendered frame's, which only presents the persistent
    /// layers again), a readback for a screenshot, the present pass and egui; then presents.
    fn record_and_present(&mut self, ui: &UiFrame, view: Result<View>) -> Result<Option<Drawn>> {
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
    fn timings(&mut self, drawn: &Drawn) -> Result<()> {
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
    fn stream_requests(&mut self) -> Result<()> {
        let (Prepared::Paged(p, s), Some(view)) = (&mut self.gpu.scene, &self.gpu.last_view) else {
            self.session.model.streaming = None;
            return Ok(());
        };
        let paged = &mut p.volume.paged;
        let feedback = paged.take_feedback()?;
        paged.cache.touch(&feedback.used);
        s.request(paged, view, &feedback.wanted, Order::CoarseFirst);
        self.session.model.streaming = Some(stream_status(s, paged));
        Ok(())
    }

    /// Whether bricks are on their way (the loop keeps drawing until they are up).
    fn streaming(&self) -> bool {
        matches!(&self.gpu.scene, Prepared::Paged(_, s) if s.outstanding() > 0)
    }

    /// What the frame leaves behind: the key of what it rendered, a refused setting rolled back
    /// with its message, and the screenshot written.
    fn finish_frame(&mut self, drawn: Drawn, full: bool) -> Result<()> {
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
    fn print_layout(&mut self, view: [u32; 4], ppp: f32) {
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
    fn view_rect_pixels(&self, r: egui::Rect, ppp: f32) -> [u32; 4] {
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

    fn bench_report(&self) -> BenchReport {
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
        };
        match &self.session.bench {
            Some(b) => b.report(base),
            None => base,
        }
    }
}

/// The corner's pass times from a completed frame's, in place: a frame with the same passes as
/// the last one (every steady frame) allocates nothing.
fn set_gpu_ms(shown: &mut Vec<(String, f64)>, passes: &[vellum_gpu::PassTime]) {
    let same = shown.len() == passes.len() && shown.iter().zip(passes).all(|(s, p)| s.0 == p.name);
    if same {
        for (s, p) in shown.iter_mut().zip(passes) {
            s.1 = p.ms;
        }
    } else {
        *shown = passes.iter().map(|p| (p.name.clone(), p.ms)).collect();
    }
}
