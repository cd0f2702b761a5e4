//! The viewer's panels, drawn with egui over the volume view: files and scenes, camera, focus,
//! the transfer-function editor over the histogram, styles and their parameters, importance
//! modulation, renderer and lighting, and the timings. The panels only edit a [`Model`]; the
//! window loop turns the edits into GPU state.

use egui::{Color32, Pos2, Rect, Sense, Stroke, Vec2};
use std::collections::BTreeSet;
use vellum_render::classify::modulation::{ColorMode, ColorModulation, Modulation};
use vellum_render::classify::otf::{Curve, OcclusionTf, Region, Shape};
use vellum_render::classify::transfer::{ControlPoint, TransferFunction, PRESETS};
use vellum_render::classify::Focus;
use vellum_render::passes::occlusion::Spectrum;
use vellum_render::render::raycast::RayOptions;
use vellum_render::render::scene::{ClassificationSpec, NamedView, Scene, StyleSpec};
use vellum_render::render::style::STYLES;
use vellum_volume::feature::map::{FeatureMap, Node};

pub(crate) mod channels;
mod features;
mod occlusion;
mod rendering;
pub(crate) mod segments;
mod transfer;

pub use channels::ChannelRow;
use channels::*;
pub use features::visible_map;
use features::*;
use occlusion::*;
use rendering::*;
pub use segments::Segments;
use segments::*;
use transfer::*;

/// What the panels ask the window loop to do.
#[derive(Default, Debug)]
pub struct Requests {
    pub open: Option<String>,
    pub load_scene: Option<String>,
    pub save_scene: Option<String>,
    pub screenshot: bool,
    pub reset_camera: bool,
    pub quit: bool,
    /// A time point of the store to show.
    pub time: Option<usize>,
}

/// The state the panels edit and show.
pub struct Model {
    /// The scene being viewed: the same structure `vellum render --scene` reads.
    pub scene: Scene,
    /// The 1D transfer function being edited (the scene's classification when it is one).
    pub tf: TransferFunction,
    /// Whether `tf` differs from what the scene's classification names.
    pub tf_edited: bool,
    /// Histogram of the volume over its data range, 256 bins.
    pub histogram: Vec<u64>,
    /// Data range of the volume (data units).
    pub range: [f64; 2],
    pub dims: [usize; 3],
    pub oriented: bool,
    /// A line for the user: what happened last, or what went wrong.
    pub message: String,
    /// A load in progress, by name.
    pub loading: Option<String>,
    /// The input's time points, the one shown, and whether they play.
    pub times: usize,
    pub time: usize,
    pub playing: bool,
    pub open_path: String,
    pub scene_path: String,
    /// Where the transfer function is loaded from and saved to (the project's TF JSON).
    pub tf_path: String,
    pub log_histogram: bool,
    /// Selected control point of the TF editor.
    pub selected: Option<usize>,
    /// Shift and scale applied to the whole transfer function (window/level), since the last preset.
    pub shift: f32,
    pub scale: f32,
    /// The TF before shift and scale.
    pub tf_base: TransferFunction,
    /// Frame statistics shown in the corner.
    pub fps: f64,
    pub gpu_ms: Vec<(String, f64)>,
    /// The brick cache's line (resident, requested, streamed), when the volume is streamed.
    pub streaming: Option<String>,
    pub render_size: [u32; 2],
    pub interactive: bool,
    pub requests: Requests,
    /// Where named widgets were last drawn (points), for `VELLUM_VIEW_LAYOUT`: `tf-editor`,
    /// `spectrum`, `feature:LABEL` and `label:ID` (their visibility boxes).
    pub marks: std::collections::BTreeMap<String, Rect>,
    /// The feature map (FM5) when the scene is classified by one; its colours are edited here.
    pub features: Option<FeatureMap>,
    /// Labels of the features the user has hidden (transparent).
    pub hidden: BTreeSet<String>,
    /// Whether the feature map was edited since it was loaded (saved beside the scene).
    pub features_edited: bool,
    /// The segments of a label volume beside the input, when the scene has one (the scene's
    /// `labels` spec holds what the panel edits).
    pub segments: Option<Segments>,
    /// The channels mixed in one ray, when the scene mixes several.
    pub channels: Option<Vec<ChannelRow>>,
    /// The occlusion transfer function (OS4, OS5) when the scene is classified by one.
    pub otf: Option<OcclusionTf>,
    /// Whether the OTF's table or its AO parameters changed since it was loaded.
    pub otf_edited: bool,
    /// The occlusion spectrum of the current volume, and its texture for egui.
    pub spectrum: Option<Spectrum>,
    pub spectrum_texture: Option<egui::TextureHandle>,
    /// Colour and opacity of the next tagged region.
    pub brush: [f32; 4],
    /// A rectangle being dragged on the spectrum: its corners as (intensity, occlusion).
    pub tagging: Option<[[f32; 2]; 2]>,
    /// A curve handle being dragged on the spectrum: the curve and which handle.
    pub curve_drag: Option<(usize, CurveHandle)>,
    /// Recompute the occlusion volume (the button).
    pub recompute_occlusion: bool,
    /// The radius of an occlusion volume being recomputed, while it is.
    pub occlusion_busy: Option<u32>,
    /// The AO radius or mapping changed since the occlusion volume was computed.
    pub occlusion_params_changed: bool,
}

impl Model {
    /// A model for `scene` with its transfer function `tf` and the volume's statistics.
    pub fn new(scene: Scene, tf: TransferFunction) -> Self {
        let time = scene.input.time.unwrap_or(0);
        Model {
            scene,
            tf_base: tf.clone(),
            tf,
            tf_edited: false,
            histogram: vec![0; 256],
            range: [0.0, 1.0],
            dims: [1, 1, 1],
            oriented: false,
            message: String::new(),
            times: 1,
            time,
            playing: false,
            loading: None,
            open_path: String::new(),
            scene_path: "vellum.scene.json".into(),
            tf_path: "vellum.tf.json".into(),
            log_histogram: true,
            selected: None,
            shift: 0.0,
            scale: 1.0,
            fps: 0.0,
            gpu_ms: Vec::new(),
            streaming: None,
            render_size: [0, 0],
            interactive: false,
            requests: Requests::default(),
            marks: Default::default(),
            features: None,
            hidden: BTreeSet::new(),
            features_edited: false,
            segments: None,
            channels: None,
            otf: None,
            otf_edited: false,
            spectrum: None,
            spectrum_texture: None,
            brush: [1.0, 0.6, 0.2, 0.5],
            tagging: None,
            curve_drag: None,
            recompute_occlusion: false,
            occlusion_busy: None,
            occlusion_params_changed: false,
        }
    }

    /// Starts over for a newly opened volume: [`Model::new`]'s state for `scene` and `tf`,
    /// keeping what belongs to the session rather than to the volume: the file paths, the
    /// histogram's scale, the brush, the frame figures, pending requests, the spectrum's marks and
    /// the occlusion worker's state. What the volume brings (histogram, range, spectrum, ...) the
    /// caller sets.
    pub fn reopen(&mut self, scene: Scene, tf: TransferFunction) {
        let old = std::mem::replace(self, Model::new(scene, tf));
        self.loading = old.loading;
        self.playing = old.playing;
        self.open_path = old.open_path;
        self.scene_path = old.scene_path;
        self.tf_path = old.tf_path;
        self.log_histogram = old.log_histogram;
        self.fps = old.fps;
        self.gpu_ms = old.gpu_ms;
        self.streaming = old.streaming;
        self.render_size = old.render_size;
        self.interactive = old.interactive;
        self.requests = old.requests;
        self.marks = old.marks;
        self.brush = old.brush;
        self.tagging = old.tagging;
        self.curve_drag = old.curve_drag;
        self.recompute_occlusion = old.recompute_occlusion;
        self.occlusion_busy = old.occlusion_busy;
    }

    /// Replaces the transfer function with `tf`, named in the scene as `name` (a preset or a file).
    fn set_tf(&mut self, tf: TransferFunction, name: &str) {
        self.tf = tf.clone();
        self.tf_base = tf;
        self.tf_edited = false;
        self.shift = 0.0;
        self.scale = 1.0;
        self.selected = None;
        self.scene.classification = ClassificationSpec::Transfer(name.to_string());
    }

    /// Applies shift and scale to `tf_base` (x' = (x − 0.5)·scale + 0.5 + shift, clamped).
    fn apply_window(&mut self) {
        let mut pts: Vec<ControlPoint> = self
            .tf_base
            .points
            .iter()
            .map(|p| ControlPoint {
                x: ((p.x - 0.5) * self.scale + 0.5 + self.shift).clamp(0.0, 1.0),
                rgba: p.rgba,
            })
            .collect();
        pts.sort_by(|a, b| a.x.total_cmp(&b.x));
        if let Ok(tf) = TransferFunction::new(self.tf_base.name.clone(), pts) {
            self.tf = tf;
            self.tf_edited = true;
        }
    }
}

/// Draws every panel for one frame and returns the rectangle left for the volume view, in
/// points. The panel is hidden (key H) with `show_panel` false: the view is then the window.
pub fn draw(ui: &mut egui::Ui, m: &mut Model, show_panel: bool) -> Rect {
    if show_panel {
        egui::Panel::left("vellum")
            .default_size(330.0)
            .resizable(true)
            .show(ui, |ui| {
                egui::ScrollArea::vertical().show(ui, |ui| panel(ui, m));
            });
    }
    let view = ui.available_rect_before_wrap();
    let ctx = ui.ctx().clone();
    egui::Area::new(egui::Id::new("stats"))
        .anchor(egui::Align2::RIGHT_TOP, [-8.0, 8.0])
        .interactable(false)
        .show(&ctx, |ui| stats(ui, m));
    view
}

fn stats(ui: &mut egui::Ui, m: &Model) {
    let text = |s: String| {
        egui::Label::new(
            egui::RichText::new(s)
                .monospace()
                .color(Color32::LIGHT_GRAY),
        )
        .extend()
    };
    ui.add(text(format!(
        "{:5.1} fps  {}x{}{}",
        m.fps,
        m.render_size[0],
        m.render_size[1],
        if m.interactive { " (interactive)" } else { "" }
    )));
    for (name, ms) in &m.gpu_ms {
        ui.add(text(format!("{name:<14} {ms:8.2} ms")));
    }
    if let Some(s) = &m.streaming {
        ui.add(text(s.clone()));
    }
}

fn panel(ui: &mut egui::Ui, m: &mut Model) {
    if let Some(what) = &m.loading {
        ui.horizontal(|ui| {
            ui.spinner();
            ui.label(format!("loading {what}…"));
        });
    }
    if !m.message.is_empty() {
        ui.label(egui::RichText::new(&m.message).color(Color32::from_rgb(255, 200, 120)));
    }
    egui::CollapsingHeader::new("File")
        .default_open(true)
        .show(ui, |ui| files(ui, m));
    if m.times > 1 {
        egui::CollapsingHeader::new("Time")
            .default_open(true)
            .show(ui, |ui| time(ui, m));
    }
    if m.segments.is_some() {
        egui::CollapsingHeader::new("Segments")
            .default_open(true)
            .show(ui, |ui| segments(ui, m));
    }
    if m.channels.is_some() {
        egui::CollapsingHeader::new("Channels")
            .default_open(true)
            .show(ui, |ui| channels(ui, m));
    }
    egui::CollapsingHeader::new("Camera")
        .default_open(false)
        .show(ui, |ui| camera(ui, m));
    egui::CollapsingHeader::new("Focus")
        .default_open(true)
        .show(ui, |ui| focus(ui, m));
    egui::CollapsingHeader::new("Transfer function")
        .default_open(true)
        .show(ui, |ui| transfer(ui, m));
    if m.otf.is_some() {
        egui::CollapsingHeader::new("Occlusion spectrum")
            .default_open(true)
            .show(ui, |ui| occlusion(ui, m));
    }
    if m.features.is_some() {
        egui::CollapsingHeader::new("Feature map")
            .default_open(true)
            .show(ui, |ui| features(ui, m));
    }
    egui::CollapsingHeader::new("Style")
        .default_open(false)
        .show(ui, |ui| style(ui, m));
    egui::CollapsingHeader::new("Importance")
        .default_open(false)
        .show(ui, |ui| importance(ui, m));
    egui::CollapsingHeader::new("Renderer and lighting")
        .default_open(false)
        .show(ui, |ui| renderer(ui, m));
}

/// The time points of a store: a slider and a play button.
fn time(ui: &mut egui::Ui, m: &mut Model) {
    ui.horizontal(|ui| {
        let label = if m.playing { "pause" } else { "play" };
        if ui.button(label).clicked() {
            m.playing = !m.playing;
        }
        let mut t = m.time;
        let slider = egui::Slider::new(&mut t, 0..=m.times - 1).text(format!("of {}", m.times));
        if ui.add(slider).changed() {
            m.playing = false;
            m.requests.time = Some(t);
        }
    });
}

fn files(ui: &mut egui::Ui, m: &mut Model) {
    ui.label(format!(
        "{}  ({}×{}×{}, {:.4}..{:.4})",
        m.scene.input.path, m.dims[0], m.dims[1], m.dims[2], m.range[0], m.range[1]
    ));
    ui.horizontal(|ui| {
        let field = ui.add(
            egui::TextEdit::singleline(&mut m.open_path)
                .hint_text("file, DICOM folder or phantom:NAME:N"),
        );
        let button = ui.button("Open");
        m.marks.insert("open-path".into(), field.rect);
        m.marks.insert("open-button".into(), button.rect);
        if button.clicked() && !m.open_path.trim().is_empty() {
            m.requests.open = Some(m.open_path.trim().to_string());
        }
    });
    ui.horizontal(|ui| {
        ui.add(egui::TextEdit::singleline(&mut m.scene_path).hint_text("scene.json"));
        if ui.button("Load").clicked() {
            m.requests.load_scene = Some(m.scene_path.clone());
        }
        if ui.button("Save").clicked() {
            m.requests.save_scene = Some(m.scene_path.clone());
        }
    });
    if ui.button("Screenshot (S)").clicked() {
        m.requests.screenshot = true;
    }
    ui.label("Drop a file on the window to open it. H hides this panel.");
}

fn camera(ui: &mut egui::Ui, m: &mut Model) {
    ui.label("Left drag orbits, right or shift drag pans, the wheel zooms, a double click resets; keys 1–6 give the axis views, O toggles orthographic.");
    ui.checkbox(&mut m.scene.camera.ortho, "orthographic");
    ui.horizontal_wrapped(|ui| {
        for (i, (v, name)) in [
            (NamedView::Anterior, "anterior"),
            (NamedView::Posterior, "posterior"),
            (NamedView::Left, "left"),
            (NamedView::Right, "right"),
            (NamedView::Superior, "superior"),
            (NamedView::Inferior, "inferior"),
        ]
        .into_iter()
        .enumerate()
        {
            if ui.button(format!("{} {name}", i + 1)).clicked() {
                set_view(&mut m.scene, v);
            }
        }
    });
    if ui.button("Reset").clicked() {
        m.requests.reset_camera = true;
    }
}

/// Looks along a named axis view at the fitted distance.
pub fn set_view(scene: &mut Scene, v: NamedView) {
    scene.camera.view = Some(v);
    scene.camera.azimuth = None;
    scene.camera.elevation = None;
    scene.camera.distance = None;
    scene.camera.pan = [0.0; 2];
}

fn focus(ui: &mut egui::Ui, m: &mut Model) {
    let [lo, hi] = m.range;
    let mut kind = match m.scene.focus {
        Focus::None => 0,
        Focus::Iso(_) => 1,
        Focus::Range { .. } => 2,
    };
    ui.horizontal(|ui| {
        ui.radio_value(&mut kind, 0, "none");
        ui.radio_value(&mut kind, 1, "isovalue");
        ui.radio_value(&mut kind, 2, "range");
    });
    let mid = lo + 0.5 * (hi - lo);
    m.scene.focus = match (kind, m.scene.focus) {
        (0, _) => Focus::None,
        (1, Focus::Iso(v)) => Focus::Iso(v),
        (1, Focus::Range { lo: a, .. }) => Focus::Iso(a),
        (1, _) => Focus::Iso(mid),
        (2, Focus::Range { lo, hi }) => Focus::Range { lo, hi },
        (2, Focus::Iso(v)) => Focus::Range { lo: v, hi },
        (_, _) => Focus::Range { lo: mid, hi },
    };
    match &mut m.scene.focus {
        Focus::Iso(v) => {
            ui.add(egui::Slider::new(v, lo..=hi).text("iso"));
        }
        Focus::Range { lo: a, hi: b } => {
            ui.add(egui::Slider::new(a, lo..=hi).text("from"));
            ui.add(egui::Slider::new(b, lo..=hi).text("to"));
            if *b < *a {
                *b = *a;
            }
        }
        Focus::None => {
            ui.label("Everything is context; styles need a focus.");
        }
    }
}

fn style(ui: &mut egui::Ui, m: &mut Model) {
    let current = m
        .scene
        .style
        .as_ref()
        .and_then(|s| s.resolve().ok())
        .map(|s| s.def.number);
    let label = current
        .and_then(|n| STYLES.iter().find(|d| d.number == n))
        .map_or("none".to_string(), |d| format!("{} {}", d.number, d.name));
    egui::ComboBox::from_label("style")
        .selected_text(label)
        .show_ui(ui, |ui| {
            if ui.selectable_label(current.is_none(), "none").clicked() {
                m.scene.style = None;
            }
            for d in STYLES.iter() {
                let reason = d.unavailable_reason().or_else(|| {
                    (d.needs_focus() && m.scene.focus == Focus::None)
                        .then(|| "needs a focus (set one under Focus)".to_string())
                });
                let r = ui.add_enabled(
                    reason.is_none(),
                    egui::Button::selectable(
                        current == Some(d.number),
                        format!("{} {}", d.number, d.name),
                    ),
                );
                let r = match &reason {
                    Some(why) => r.on_disabled_hover_text(why.as_str()),
                    None => r,
                };
                if r.clicked() {
                    let params = m.scene.style.as_ref().map(|s| s.params).unwrap_or_default();
                    m.scene.style = Some(StyleSpec {
                        style: serde_json::json!(d.number),
                        params,
                    });
                    m.scene.one_pass = false;
                }
            }
        });
    if let Some(spec) = &mut m.scene.style {
        let p = &mut spec.params;
        ui.horizontal(|ui| {
            ui.label("edges");
            ui.color_edit_button_rgb(&mut p.edge_color);
        });
        ui.add(egui::Slider::new(&mut p.edge_width, 1..=4).text("edge width"));
        ui.add(egui::Slider::new(&mut p.sobel_threshold, 0.0..=1.0).text("Sobel threshold"));
        ui.add(egui::Slider::new(&mut p.dog_sigma, 0.5..=4.0).text("DoG σ"));
        ui.add(egui::Slider::new(&mut p.canny_sigma, 0.5..=4.0).text("Canny σ"));
        ui.add(egui::Slider::new(&mut p.canny_high, 0.01..=1.0).text("Canny high"));
        ui.add(egui::Slider::new(&mut p.kuwahara_radius, 1..=8).text("Kuwahara radius"));
        ui.add(egui::Slider::new(&mut p.saturation, 0.0..=3.0).text("saturation"));
        ui.add(egui::Slider::new(&mut p.line_angle, 0.0..=60.0).text("line angle (°)"));
        ui.add(
            egui::Slider::new(&mut p.line_derivative_threshold, 0.0..=1.0).text("line threshold"),
        );
        line_smoothing(ui, &mut p.line_smooth);
    }
}

/// The line-smoothing control: `auto` (by the data's quantisation) or a radius.
fn line_smoothing(ui: &mut egui::Ui, smooth: &mut vellum_render::render::style::LineSmooth) {
    use vellum_render::render::style::LineSmooth;
    ui.horizontal(|ui| {
        let mut auto = *smooth == LineSmooth::Auto;
        if ui
            .checkbox(&mut auto, "auto")
            .on_hover_text("smooth quantised data (integer voxels) by radius 1 or 2; float data not at all")
            .changed()
        {
            *smooth = if auto { LineSmooth::Auto } else { LineSmooth::Radius(0) };
        }
        if let LineSmooth::Radius(r) = smooth {
            ui.add(egui::Slider::new(r, 0..=8).text("line smoothing (voxels)"))
                .on_hover_text("Gaussian radius (σ = R/3) applied before extracting lines; 3 against noise on CT and MRI");
        }
    });
}
