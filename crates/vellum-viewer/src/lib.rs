#![warn(missing_docs)]
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
//! window's resolution (and a volume in core with one plane per voxel, not two) and the present
//! pass scales them up; [`REFINE_AFTER`] after the last
//! change, one frame at full resolution follows and the loop goes idle until the next event.

mod bench;
mod files;
mod frame;
mod loading;
mod playback;
mod running;
mod session;
mod timeline;
mod ui;

// The viewer speaks Vulkan where it hands egui-ash-renderer what its API takes: the swapchain's
// format, the command buffer of the frame and its extent, and the stage the present waits at.
use ash::vk;
use bench::BenchLog;
pub use bench::{BenchReport, FrameRow};
pub use frame::UPLOADS_PER_FRAME;
use session::{Budget, Drag, DrawnKey, Edit, KeyPress, Loaded, Session, SessionSetup};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};
use vellum_error::{Error, Result};
use vellum_gpu::commands::CommandPool;
use vellum_gpu::graphics::{begin_rendering_view, end_rendering, GraphicsDesc, GraphicsPipeline};
use vellum_gpu::swapchain::Swapchain;
use vellum_gpu::{
    Access, Bind, BindingKind, Context, ContextDesc, Frames, FramesDesc, Presentation, Sampler,
    SubmitSync,
};
use vellum_render::render::frame::Renderer;
use vellum_render::render::scene::Scene;
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
    /// Keep every frame's figures in the report's `rows` (`--bench-log`).
    pub bench_rows: bool,
    /// GPU memory for the volume's textures in MiB; a store that needs more is streamed through
    /// the brick cache (default: half the device's largest heap).
    pub gpu_budget: Option<f64>,
    /// Host memory in MiB for a streamed store's decoded chunks and the bricks waiting for the
    /// GPU (default 1024).
    pub memory_budget: Option<f64>,
    /// Start playing a store's time points (`--play`).
    pub play: bool,
    /// Time points per second while playing, at most (`--play-rate`).
    pub play_rate: f64,
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
    budget: Budget,
    /// The normals pass every volume put on the GPU in core goes through, built once.
    normals: vellum_render::passes::normals::Normals,
    /// The next time point of a playing series, read and put on the GPU ahead of its turn.
    ahead: Option<(String, session::Loaded, Prepared)>,
}

/// The pointer and keyboard: a drag in progress, modifiers, the last click (for the double
/// click that resets the camera), and when the view last changed (for adaptive quality).
struct Input {
    drag: Option<(Drag, [f64; 2])>,
    cursor: [f64; 2],
    shift: bool,
    ctrl: bool,
    last_click: Option<Instant>,
    /// Where the left button went down over the view: a release there is a click that picks.
    pressed_at: Option<[f64; 2]>,
    last_change: Instant,
    /// Whether the full-resolution frame has been drawn since the last change.
    refined: bool,
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
                    ElementState::Released => r.release(button),
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
        r.poll_ahead();
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
            || r.session.playing()
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
