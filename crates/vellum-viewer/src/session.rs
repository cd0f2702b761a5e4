//! The viewer's session, apart from the window: the model the panels edit (with its scene), what
//! of it the GPU state holds, the volume on the host, the work in flight on worker threads
//! (loading a volume, recomputing the occlusion volume) and the files it writes. It opens no
//! window and records no GPU work: an edit becomes an [`Edit`] that the shell (`lib.rs`) applies
//! to the GPU state, and a camera gesture changes the scene's camera given the camera the shell
//! resolved. Its unit tests run without a window or a device.

use crate::bench::BenchLog;
pub(crate) use crate::loading::{load, Budget, Loaded};
use crate::ui::{self, Model};
use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::time::Instant;
use vellum_error::{Error, Result};
use vellum_render::classify::modulation::Modulation;
use vellum_render::classify::otf::OcclusionTf;
use vellum_render::classify::transfer::TransferFunction;
use vellum_render::classify::Focus;
use vellum_render::passes::occlusion::{OcclusionOutput, OcclusionParams, Spectrum};
use vellum_render::render::camera::Camera;
use vellum_render::render::scene::{CameraSpec, ClassificationSpec, InputSpec, NamedView, Scene};
use vellum_render::render::view::View;
use vellum_volume::Volume;

/// An occlusion volume being recomputed on a worker thread. The worker opens its own Vulkan
/// device (a second queue on the same GPU) and hands back the volume and spectrum on the host;
/// the shell uploads them in one short submission. The window keeps rendering meanwhile, and no
/// submission of the window's context ever happens off its thread, which the deferred release
/// of vellum-gpu's lifetime.rs relies on.
pub(crate) struct PendingOcclusion {
    rx: mpsc::Receiver<Result<OcclusionOutput>>,
    pub(crate) radius: u32,
    pub(crate) started: Instant,
    generation: u64,
    /// Frames presented while it ran, and the longest time between two of them.
    pub(crate) frames: u32,
    pub(crate) longest_ms: f64,
}

/// What the targets hold: the view and the applied state of the last frame rendered, and the
/// volume's epoch.
#[derive(Clone, PartialEq)]
pub(crate) struct DrawnKey {
    pub(crate) view: View,
    pub(crate) scene: Scene,
    pub(crate) tf: TransferFunction,
    pub(crate) otf: Option<OcclusionTf>,
    pub(crate) epoch: u64,
}

/// Camera drag in progress.
#[derive(Copy, Clone, Debug, PartialEq)]
pub(crate) enum Drag {
    Orbit,
    Pan,
}

/// A key the session acts on, from the window's keyboard.
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum KeyPress {
    Escape,
    Char(String),
}

/// A change of the GPU state that an edit of the scene asks for, applied by the shell.
#[derive(Debug, PartialEq)]
pub(crate) enum Edit {
    Focus(Focus),
    Transfer(TransferFunction),
    OcclusionTable(Vec<[f32; 4]>),
    Modulation(Modulation),
    /// The segments' visibility, colours or focus changed (the same label volume).
    Labels(vellum_render::classify::labels::LabelSpec),
    /// The mixed channels' transfer functions, one per channel in mixing order.
    Channels(Vec<TransferFunction>),
}

/// What the shell tells a new session besides the first volume.
pub(crate) struct SessionSetup {
    /// The device the window renders on, for the occlusion worker's own context.
    pub(crate) device: Option<String>,
    /// The device's name, for the first message.
    pub(crate) device_name: String,
    pub(crate) screenshot_dir: PathBuf,
    pub(crate) bench: Option<BenchLog>,
    /// What a volume opens within: GPU memory for its textures (a store that needs more is
    /// streamed), and host memory for a streamed one.
    pub(crate) budget: Budget,
    /// Start playing the time points of a store.
    pub(crate) play: bool,
    /// How long a playing time point stays on screen, at least (one over the play rate).
    pub(crate) step: std::time::Duration,
}

/// The session: the model the panels edit (with the scene), what of it is applied to the GPU
/// state, the volume on the host, the work in flight on worker threads, and the files it writes.
pub(crate) struct Session {
    pub(crate) model: Model,
    /// The scene as last applied to the GPU state, to see what changed.
    pub(crate) applied: Scene,
    pub(crate) applied_tf: TransferFunction,
    pub(crate) applied_otf: Option<OcclusionTf>,
    /// The channel rows as last applied.
    pub(crate) applied_channels: Option<Vec<crate::ui::ChannelRow>>,
    /// The volume on the host, for recomputing what depends on it (the occlusion volume).
    pub(crate) volume: Volume,
    /// The camera of the loaded scene, for reset.
    home: CameraSpec,
    pending_load: Option<mpsc::Receiver<Result<Loaded>>>,
    /// The next time point, read ahead while playing.
    pub(crate) prefetch: Option<crate::timeline::Prefetch<Result<Loaded>>>,
    /// The time point the shell holds on the GPU ahead of its turn, and whether its turn came.
    pub(crate) ready: Option<usize>,
    pub(crate) swap: bool,
    /// While playing, when the next time point is due: one `step` after the current one was
    /// due, so that a late frame does not push every later time point back.
    pub(crate) due_at: Instant,
    /// How long a playing time point stays on screen, at least.
    pub(crate) step: std::time::Duration,
    /// The occlusion volume being recomputed on a worker thread.
    pub(crate) pending_occlusion: Option<PendingOcclusion>,
    /// Counts the volumes loaded, so that an occlusion volume computed for an earlier one is
    /// dropped.
    generation: u64,
    device: Option<String>,
    /// What the targets hold. A frame that would render the same again only presents them (idle
    /// redraws for a spinner, hover or a screenshot cost no volume rendering).
    pub(crate) last_drawn: Option<DrawnKey>,
    /// Counts replacements of GPU volume state (loads, occlusion volumes).
    pub(crate) epoch: u64,
    pub(crate) screenshot: Option<PathBuf>,
    pub(crate) screenshot_dir: PathBuf,
    /// The `--bench` orbit's bookkeeping, in bench mode.
    pub(crate) bench: Option<BenchLog>,
    pub(crate) budget: Budget,
}

impl Session {
    /// The session of the first volume, `loaded`, whose GPU state has `dims` voxels (a streamed
    /// store's level 0) and made the occlusion `spectrum` if it has one.
    pub(crate) fn new(
        loaded: Loaded,
        spectrum: Option<Spectrum>,
        dims: [usize; 3],
        setup: SessionSetup,
    ) -> Self {
        let mut model = Model::new(loaded.scene.clone(), loaded.tf.clone());
        model.histogram = loaded.histogram;
        model.features = loaded.features;
        model.otf = loaded.otf.clone();
        model.spectrum = spectrum;
        model.range = loaded.range;
        model.dims = dims;
        model.oriented = loaded.volume.geometry.is_oriented();
        model.times = loaded.times;
        model.message = format!("{} on {}", loaded.scene.input.path, setup.device_name);
        let beside = |name: &str| {
            setup
                .screenshot_dir
                .join(name)
                .to_string_lossy()
                .into_owned()
        };
        model.scene_path = beside("vellum.scene.json");
        model.tf_path = beside("vellum.tf.json");
        model.playing = setup.play;
        let mut session = Session {
            home: loaded.scene.camera.clone(),
            applied: loaded.scene,
            applied_tf: loaded.tf,
            applied_otf: loaded.otf,
            applied_channels: None,
            volume: loaded.volume,
            model,
            pending_load: None,
            prefetch: None,
            ready: None,
            swap: false,
            due_at: Instant::now() + setup.step,
            step: setup.step,
            pending_occlusion: None,
            generation: 0,
            device: setup.device,
            last_drawn: None,
            epoch: 0,
            screenshot: None,
            screenshot_dir: setup.screenshot_dir,
            bench: setup.bench,
            budget: setup.budget,
        };
        session.fix_series_scale();
        session
    }

    /// Makes the scene's camera explicit (angles and distance) from `cam`, the camera resolved
    /// for the volume and window, so that a gesture can change it.
    fn make_explicit(&mut self, cam: &Camera) {
        let c = &mut self.model.scene.camera;
        c.view = None;
        c.azimuth = Some(cam.azimuth_deg);
        c.elevation = Some(cam.elevation_deg);
        c.distance = Some(cam.distance);
    }

    /// A drag of `d` window pixels from `cam` in a view `view_h` pixels high: an orbit turns
    /// 0.4° a pixel (the elevation held within ±90°); a pan moves the target with the pointer.
    pub(crate) fn drag(&mut self, cam: &Camera, kind: Drag, d: [f64; 2], view_h: u32) {
        self.make_explicit(cam);
        let h = view_h.max(1) as f32;
        let c = &mut self.model.scene.camera;
        match kind {
            Drag::Orbit => {
                c.azimuth = Some((cam.azimuth_deg - 0.4 * d[0] as f32).rem_euclid(360.0));
                c.elevation = Some((cam.elevation_deg + 0.4 * d[1] as f32).clamp(-90.0, 90.0));
            }
            Drag::Pan => {
                // The visible height at the target, in bounding-sphere radii.
                let span = 2.0 * cam.distance * (0.5 * cam.fov_y_deg.to_radians()).tan();
                c.pan[0] -= d[0] as f32 * span / h;
                c.pan[1] += d[1] as f32 * span / h;
            }
        }
    }

    /// `steps` wheel steps from `cam`: each brings the eye 10 % closer, within the volume's
    /// bounding sphere (perspective) and 100 radii.
    pub(crate) fn zoom(&mut self, cam: &Camera, steps: f64) {
        self.make_explicit(cam);
        let min = if cam.ortho { 0.05 } else { 1.05 };
        self.model.scene.camera.distance =
            Some((cam.distance * 0.9f32.powf(steps as f32)).clamp(min, 100.0));
    }

    /// The loaded scene's camera again.
    pub(crate) fn reset_camera(&mut self) {
        self.model.scene.camera = self.home.clone();
    }

    /// A key pressed outside the panels: quit, screenshot, save the scene (with ctrl),
    /// orthographic, reset, and the six named views. Returns true for the key that shows or
    /// hides the panel, which is the shell's.
    pub(crate) fn key(&mut self, key: &KeyPress, ctrl: bool) -> bool {
        let c = match key {
            KeyPress::Escape => {
                self.model.requests.quit = true;
                return false;
            }
            KeyPress::Char(c) => c.to_lowercase(),
        };
        match c.as_str() {
            "q" => self.model.requests.quit = true,
            "s" if ctrl => self.model.requests.save_scene = Some(self.model.scene_path.clone()),
            "s" => self.model.requests.screenshot = true,
            "o" => self.model.scene.camera.ortho = !self.model.scene.camera.ortho,
            "r" => self.reset_camera(),
            "h" => return true,
            d @ ("1" | "2" | "3" | "4" | "5" | "6") => {
                let v = [
                    NamedView::Anterior,
                    NamedView::Posterior,
                    NamedView::Left,
                    NamedView::Right,
                    NamedView::Superior,
                    NamedView::Inferior,
                ][d.parse::<usize>().unwrap_or(1) - 1];
                ui::set_view(&mut self.model.scene, v);
            }
            _ => {}
        }
        false
    }

    /// Starts loading `input` on a worker thread, keeping the rest of the scene: presets carry
    /// over to a new volume; files made for the old one (features, OTFs), the focus, the style
    /// and the camera do not.
    pub(crate) fn start_load_input(&mut self, input: String) {
        let mut scene = self.model.scene.clone();
        scene.input = InputSpec::new(input.clone());
        if !matches!(scene.classification, ClassificationSpec::Transfer(_)) {
            scene.classification = ClassificationSpec::default();
        }
        scene.focus = Focus::None;
        scene.style = None;
        scene.camera = Default::default();
        // A series' channel scales are the old input's.
        if let Some(c) = scene.channels.as_mut() {
            c.scales.clear();
        }
        self.start_load(input, scene);
    }

    /// Starts loading `scene` on a worker thread; `what` names it in the messages.
    pub(crate) fn start_load(&mut self, what: String, scene: Scene) {
        let (tx, rx) = mpsc::channel();
        let budget = self.budget.clone();
        std::thread::spawn(move || {
            let _ = tx.send(load(scene, &budget));
        });
        self.model.loading = Some(what);
        self.pending_load = Some(rx);
    }

    /// Makes `answer`, a load already under way (a time point read ahead), the pending load.
    pub(crate) fn take_over_load(&mut self, what: String, answer: mpsc::Receiver<Result<Loaded>>) {
        self.model.loading = Some(what);
        self.pending_load = Some(answer);
    }

    /// Whether a volume is loading.
    pub(crate) fn loading(&self) -> bool {
        self.pending_load.is_some()
    }

    /// A finished load, with what it was called: `None` while the worker is busy.
    pub(crate) fn take_load(&mut self) -> Option<(String, Result<Loaded>)> {
        let got = match self.pending_load.as_ref()?.try_recv() {
            Ok(got) => got,
            Err(mpsc::TryRecvError::Empty) => return None,
            Err(mpsc::TryRecvError::Disconnected) => Err(Error::Invalid(
                "the loader stopped without an answer".into(),
            )),
        };
        self.pending_load = None;
        Some((self.model.loading.take().unwrap_or_default(), got))
    }

    /// The volume `l` (called `what`) now drawn in place of the old one, with the GPU state's
    /// `dims` and occlusion `spectrum`: the panels start over on it.
    pub(crate) fn opened(
        &mut self,
        l: Loaded,
        what: &str,
        spectrum: Option<Spectrum>,
        dims: [usize; 3],
    ) {
        self.generation += 1;
        self.epoch += 1;
        // Another time point of the series shown: the transfer function (as edited), its
        // histogram and the scale stay those of the series, so that the frames compare.
        let step = l.scene.input.path == self.applied.input.path
            && l.scene.input.time != self.applied.input.time;
        let kept = step.then(|| crate::timeline::SeriesLook::of(&self.model));
        if step {
            if let Some(b) = self.bench.as_mut() {
                b.time_point_shown(Instant::now());
            }
        }
        self.model.reopen(l.scene.clone(), l.tf.clone());
        self.model.spectrum = spectrum;
        self.model.otf = l.otf.clone();
        self.applied_otf = l.otf;
        self.model.histogram = l.histogram;
        self.model.features = l.features;
        self.model.range = l.range;
        self.model.dims = dims;
        self.model.oriented = l.volume.geometry.is_oriented();
        self.model.times = l.times;
        self.model.time = l.scene.input.time.unwrap_or(0);
        self.due_at = crate::timeline::next_due(self.due_at, Instant::now(), self.step, step);
        self.model.message = format!("opened {what}");
        self.home = l.scene.camera.clone();
        self.applied = l.scene;
        self.applied_tf = l.tf;
        self.volume = l.volume;
        match kept {
            Some(look) => look.restore(&mut self.model),
            None => self.fix_series_scale(),
        }
    }

    /// Starts computing the occlusion volume of the host volume on a worker thread, on a
    /// context of its own.
    pub(crate) fn start_occlusion(&mut self, params: OcclusionParams) {
        let (tx, rx) = mpsc::channel();
        let volume = self.volume.clone();
        let device = self.device.clone();
        let radius = params.radius;
        // A test hook: hold the worker back this long, so that a test can show frames arriving
        // while it is busy whatever the machine's speed.
        let hold = std::env::var("VELLUM_VIEW_OCCLUSION_DELAY_MS")
            .ok()
            .and_then(|v| v.trim().parse::<u64>().ok())
            .map(std::time::Duration::from_millis);
        std::thread::spawn(move || {
            if let Some(d) = hold {
                std::thread::sleep(d);
            }
            let result = (|| {
                let ctx = vellum_gpu::Context::new(&vellum_gpu::ContextDesc {
                    validation: None,
                    device,
                })?;
                let out = vellum_render::passes::occlusion::Occlusion::new(&ctx)?
                    .compute(&volume, &params);
                ctx.report_validation();
                out
            })();
            let _ = tx.send(result);
        });
        self.model.occlusion_busy = Some(radius);
        self.pending_occlusion = Some(PendingOcclusion {
            rx,
            radius,
            started: Instant::now(),
            generation: self.generation,
            frames: 0,
            longest_ms: 0.0,
        });
    }

    /// A finished occlusion volume for the volume still shown: `None` while the worker is busy,
    /// or when the result was for a volume since replaced (it is dropped).
    pub(crate) fn take_occlusion(&mut self) -> Option<(PendingOcclusion, Result<OcclusionOutput>)> {
        let got = match self.pending_occlusion.as_ref()?.rx.try_recv() {
            Ok(got) => got,
            Err(mpsc::TryRecvError::Empty) => return None,
            Err(mpsc::TryRecvError::Disconnected) => Err(Error::Invalid(
                "the occlusion worker stopped without an answer".into(),
            )),
        };
        let p = self.pending_occlusion.take()?;
        self.model.occlusion_busy = None;
        (p.generation == self.generation).then_some((p, got))
    }

    /// The occlusion volume of `p` now sampled, with its `spectrum` in the editor.
    pub(crate) fn occlusion_attached(&mut self, p: &PendingOcclusion, spectrum: Option<Spectrum>) {
        self.epoch += 1;
        self.model.spectrum = spectrum;
        self.model.spectrum_texture = None;
        // Upload the OTF as it is now (it may have been edited meanwhile).
        self.applied_otf = None;
        self.model.message = format!(
            "occlusion at R = {} recomputed in {:.0} ms on a second device; {} frames drawn meanwhile, at most {:.0} ms apart",
            p.radius,
            p.started.elapsed().as_secs_f64() * 1e3,
            p.frames,
            p.longest_ms
        );
    }

    /// Whether the scene or the transfer function was edited since the last [`Session::apply`].
    pub(crate) fn edited(&self) -> bool {
        self.model.scene != self.applied
            || self.model.tf != self.applied_tf
            || self.model.channels != self.applied_channels
    }

    /// Turns the scene's edits into the GPU state's [`Edit`]s, for a volume whose values span
    /// `range` and which has an importance map or not. Edits that need the volume prepared
    /// again (a new input or classification kind, another importance radius) load it again on
    /// the worker thread instead. A focus outside the volume's values is refused with its
    /// sentence and set back.
    pub(crate) fn apply(&mut self, range: [f64; 2], has_importance: bool) -> Vec<Edit> {
        let (s, a) = (&self.model.scene, &self.applied);
        let radius = |x: &Scene| {
            x.modulation
                .as_ref()
                .filter(|m| m.is_active())
                .map(|m| m.importance_radius)
        };
        let label_path = |x: &Scene| x.labels.as_ref().map(|l| l.path.clone());
        let needs_prepare = s.input != a.input
            || label_path(s) != label_path(a)
            || (!matches!(s.classification, ClassificationSpec::Transfer(_))
                && s.classification != a.classification)
            || radius(s) != radius(a) && radius(s).is_some();
        if needs_prepare && self.pending_load.is_none() {
            let scene = s.clone();
            self.start_load(scene.input.path.clone(), scene);
            self.applied = self.model.scene.clone();
            return Vec::new();
        }
        if let Err(e) = s.focus.check_in(range).and(s.focus.validate()) {
            self.model.message = e.to_string();
            self.model.scene.focus = self.applied.focus;
        }
        let mut edits = vec![Edit::Focus(self.model.scene.focus)];
        if let Some(spec) = self.model.scene.labels.as_ref() {
            if self.applied.labels.as_ref() != Some(spec) {
                edits.push(Edit::Labels(spec.clone()));
            }
        }
        self.apply_occlusion(&mut edits);
        self.apply_channels(&mut edits);
        if self.model.tf != self.applied_tf {
            edits.push(Edit::Transfer(self.model.tf.clone()));
            self.applied_tf = self.model.tf.clone();
        }
        edits.push(Edit::Modulation(match &self.model.scene.modulation {
            Some(m) if has_importance => m.clone(),
            _ => Default::default(),
        }));
        self.applied = self.model.scene.clone();
        edits
    }

    /// The channels' functions when a row was edited since the last apply.
    fn apply_channels(&mut self, edits: &mut Vec<Edit>) {
        let Some(rows) = self.model.channels.as_ref() else {
            return;
        };
        if self.applied_channels.as_ref() == Some(rows) {
            return;
        }
        match rows.iter().map(|r| r.tf()).collect() {
            Ok(tfs) => {
                edits.push(Edit::Channels(tfs));
                // The channels' functions are not in the scene: the next frame draws anew.
                self.epoch += 1;
            }
            Err(e) => self.model.message = e.to_string(),
        }
        self.applied_channels = Some(rows.clone());
    }

    /// An edited OTF's table; starts recomputing the occlusion volume (and the spectrum) on a
    /// worker thread when asked.
    fn apply_occlusion(&mut self, edits: &mut Vec<Edit>) {
        let Some(otf) = self.model.otf.clone() else {
            return;
        };
        if std::mem::take(&mut self.model.recompute_occlusion) && self.pending_occlusion.is_none() {
            match vellum_render::render::scene::occlusion_params(&otf) {
                Ok(params) => self.start_occlusion(params),
                Err(e) => self.model.message = e.to_string(),
            }
        }
        if self.applied_otf.as_ref() != Some(&otf) {
            match otf.table() {
                Ok(table) => edits.push(Edit::OcclusionTable(table)),
                Err(e) => self.model.message = e.to_string(),
            }
            self.applied_otf = Some(otf);
        }
    }

    /// The `--bench` orbit's next step: 3° further round, from an explicit camera.
    pub(crate) fn bench_step(&mut self) {
        let Some(left) = self.bench.as_mut().map(|b| &mut b.left) else {
            return;
        };
        let c = &mut self.model.scene.camera;
        if c.azimuth.is_none() {
            c.view = None;
            c.azimuth = Some(0.0);
            c.elevation = Some(20.0);
        }
        c.azimuth = Some((c.azimuth.unwrap_or(0.0) + 3.0).rem_euclid(360.0));
        *left = left.saturating_sub(1);
    }

    /// A setting the renderer refused: say why, and go back to what rendered.
    pub(crate) fn refused(&mut self, e: &Error) {
        self.model.message = e.to_string();
        if self.model.scene != self.applied {
            self.model.scene = self.applied.clone();
        }
    }

    /// Open, load and save requests from the panels; a saved scene has the view's `size`.
    pub(crate) fn handle_requests(&mut self, size: [u32; 2]) {
        let req = std::mem::take(&mut self.model.requests);
        self.model.requests.screenshot = req.screenshot;
        self.model.requests.quit = req.quit;
        if req.reset_camera {
            self.reset_camera();
        }
        if let Some(input) = req.open {
            self.start_load_input(input);
        }
        if let Some(t) = req.time {
            self.show_time(t);
        }
        if let Some(path) = req.load_scene {
            match Scene::load(Path::new(&path)) {
                Ok(scene) => self.start_load(path, scene),
                Err(e) => self.model.message = e.to_string(),
            }
        }
        if let Some(path) = req.save_scene {
            self.model.message = match self.save_scene(Path::new(&path), size) {
                Ok(()) => format!("saved the scene to {path}"),
                Err(e) => e.to_string(),
            };
        }
    }
}

#[cfg(test)]
#[path = "tests/session.rs"]
mod tests;
