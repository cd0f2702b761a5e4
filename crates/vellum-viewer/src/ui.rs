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

/// What the panels ask the window loop to do.
#[derive(Default, Debug)]
pub struct Requests {
    pub open: Option<String>,
    pub load_scene: Option<String>,
    pub save_scene: Option<String>,
    pub screenshot: bool,
    pub reset_camera: bool,
    pub quit: bool,
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
    /// `spectrum`, `feature:LABEL` (its visibility box).
    pub marks: std::collections::BTreeMap<String, Rect>,
    /// The feature map (FM5) when the scene is classified by one; its colours are edited here.
    pub features: Option<FeatureMap>,
    /// Labels of the features the user has hidden (transparent).
    pub hidden: BTreeSet<String>,
    /// Whether the feature map was edited since it was loaded (saved beside the scene).
    pub features_edited: bool,
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

fn transfer(ui: &mut egui::Ui, m: &mut Model) {
    let editable = matches!(m.scene.classification, ClassificationSpec::Transfer(_));
    if !editable {
        ui.label(match &m.scene.classification {
            ClassificationSpec::Occlusion(f) => format!("occlusion transfer function {f}: edit it over the spectrum (see Occlusion spectrum)"),
            ClassificationSpec::Features(f) => format!("feature map {f}: its features set the transfer function (see Feature map)"),
            ClassificationSpec::Composed { features, occlusion } => format!("feature map {features} composed with the occlusion transfer function {occlusion}: shown as the files say (edit each alone to change it)"),
            ClassificationSpec::Transfer(_) => String::new(),
        });
        return;
    }
    ui.horizontal(|ui| {
        let current = m.tf.name.clone();
        egui::ComboBox::from_label("preset")
            .selected_text(if m.tf_edited {
                format!("{current} (edited)")
            } else {
                current
            })
            .show_ui(ui, |ui| {
                for p in PRESETS {
                    if ui.selectable_label(false, *p).clicked() {
                        if let Ok(tf) = TransferFunction::preset(p) {
                            m.set_tf(tf, p);
                        }
                    }
                }
            });
        ui.checkbox(&mut m.log_histogram, "log");
    });
    tf_editor(ui, m);
    let (s0, k0) = (m.shift, m.scale);
    ui.add(egui::Slider::new(&mut m.shift, -1.0..=1.0).text("shift"));
    ui.add(
        egui::Slider::new(&mut m.scale, 0.05..=4.0)
            .logarithmic(true)
            .text("scale"),
    );
    if s0 != m.shift || k0 != m.scale {
        m.apply_window();
    }
    if let Some(i) = m.selected.filter(|&i| i < m.tf.points.len()) {
        ui.horizontal(|ui| {
            let mut rgba = m.tf.points[i].rgba;
            ui.label(format!("point {} at {:.3}", i + 1, m.tf.points[i].x));
            if ui.color_edit_button_rgba_unmultiplied(&mut rgba).changed() {
                m.tf.points[i].rgba = rgba;
                edited(m);
            }
            if ui.button("delete").clicked() && m.tf.points.len() > 2 {
                m.tf.points.remove(i);
                m.selected = None;
                edited(m);
            }
        });
    }
    ui.label("Click to add a point, drag to move it (opacity is the height), right click deletes.");
    ui.horizontal(|ui| {
        ui.add(egui::TextEdit::singleline(&mut m.tf_path).hint_text("tf.json"));
        if ui.button("Load").clicked() {
            match TransferFunction::load(std::path::Path::new(&m.tf_path)) {
                Ok(tf) => {
                    let path = m.tf_path.clone();
                    m.set_tf(tf, &path);
                    m.message = format!("loaded the transfer function {}", m.tf_path);
                }
                Err(e) => m.message = e.to_string(),
            }
        }
        if ui.button("Save").clicked() {
            let json = m.tf.to_json();
            let path = std::path::PathBuf::from(&m.tf_path);
            m.message = match vellum_volume::output::write_atomic(&path, |w| {
                use std::io::Write;
                writeln!(w, "{json}")
            }) {
                Ok(()) => {
                    m.scene.classification = ClassificationSpec::Transfer(m.tf_path.clone());
                    m.tf_edited = false;
                    format!("saved the transfer function to {}", m.tf_path)
                }
                Err(e) => e.to_string(),
            };
        }
    });
}

/// The TF was edited directly: the edit becomes the new base of shift and scale.
fn edited(m: &mut Model) {
    m.tf_edited = true;
    m.tf_base = m.tf.clone();
    m.shift = 0.0;
    m.scale = 1.0;
}

fn tf_editor(ui: &mut egui::Ui, m: &mut Model) {
    // Clear of the scroll bar, which appears over the right edge on hover.
    let width = (ui.available_width() - 14.0).max(200.0);
    let (response, painter) = ui.allocate_painter(Vec2::new(width, 140.0), Sense::click_and_drag());
    let rect = response.rect;
    m.marks.insert("tf-editor".into(), rect);
    painter.rect_filled(rect, 2.0, Color32::from_gray(24));
    histogram(&painter, rect, &m.histogram, m.log_histogram);
    let pts = draw_tf(&painter, rect, m);
    edit_tf(ui, m, &response, rect, &pts);
}

/// The focus on the axis, the TF's colour along the bottom, its opacity curve and its points;
/// returns the points' positions.
fn draw_tf(painter: &egui::Painter, rect: Rect, m: &Model) -> Vec<Pos2> {
    // The focus interval on the axis.
    let to_x = |v: f64| {
        let t = ((v - m.range[0]) / (m.range[1] - m.range[0]).max(f64::MIN_POSITIVE)) as f32;
        rect.left() + t.clamp(0.0, 1.0) * rect.width()
    };
    match m.scene.focus {
        Focus::Iso(v) => {
            painter.vline(
                to_x(v),
                rect.y_range(),
                Stroke::new(1.5, Color32::from_rgb(90, 160, 255)),
            );
        }
        Focus::Range { lo, hi } => {
            painter.rect_filled(
                Rect::from_min_max(
                    Pos2::new(to_x(lo), rect.top()),
                    Pos2::new(to_x(hi), rect.bottom()),
                ),
                0.0,
                Color32::from_rgba_unmultiplied(90, 160, 255, 40),
            );
        }
        Focus::None => {}
    }
    let point_pos = |p: &ControlPoint| {
        Pos2::new(
            rect.left() + p.x * rect.width(),
            rect.bottom() - p.rgba[3] * rect.height(),
        )
    };
    // The TF's colour along the bottom and its opacity curve.
    for i in 0..rect.width() as usize {
        let x = i as f32 / rect.width();
        let c = m.tf.sample(x);
        let col = Color32::from_rgb(
            (c[0].clamp(0.0, 1.0) * 255.0) as u8,
            (c[1].clamp(0.0, 1.0) * 255.0) as u8,
            (c[2].clamp(0.0, 1.0) * 255.0) as u8,
        );
        let px = rect.left() + i as f32;
        painter.line_segment(
            [
                Pos2::new(px, rect.bottom() - 6.0),
                Pos2::new(px, rect.bottom()),
            ],
            Stroke::new(1.0, col),
        );
    }
    let pts: Vec<Pos2> = m.tf.points.iter().map(point_pos).collect();
    painter.add(egui::Shape::line(
        pts.clone(),
        Stroke::new(1.5, Color32::WHITE),
    ));
    for (i, p) in pts.iter().enumerate() {
        let c = m.tf.points[i].rgba;
        let fill = Color32::from_rgb(
            (c[0] * 255.0) as u8,
            (c[1] * 255.0) as u8,
            (c[2] * 255.0) as u8,
        );
        let stroke = if m.selected == Some(i) {
            Stroke::new(2.0, Color32::YELLOW)
        } else {
            Stroke::new(1.0, Color32::WHITE)
        };
        painter.circle(*p, 5.0, fill, stroke);
    }
    pts
}

/// Dragging, adding (click) and removing (right click) the TF's points.
fn edit_tf(ui: &egui::Ui, m: &mut Model, response: &egui::Response, rect: Rect, pts: &[Pos2]) {
    // Interaction: the nearest point within 8 px is the one acted on.
    let hit = |pos: Pos2| {
        pts.iter()
            .enumerate()
            .map(|(i, p)| (i, p.distance(pos)))
            .filter(|(_, d)| *d < 8.0)
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(i, _)| i)
    };
    let to_point = |pos: Pos2| {
        (
            ((pos.x - rect.left()) / rect.width()).clamp(0.0, 1.0),
            ((rect.bottom() - pos.y) / rect.height()).clamp(0.0, 1.0),
        )
    };
    // A drag starts once the pointer has moved a few pixels: pick the point under the press.
    let origin = ui.input(|i| i.pointer.press_origin());
    if response.drag_started() {
        if let Some(pos) = origin.or(response.interact_pointer_pos()) {
            m.selected = hit(pos);
        }
    }
    if response.dragged() {
        if let (Some(i), Some(pos)) = (m.selected, response.interact_pointer_pos()) {
            if i < m.tf.points.len() {
                let (x, a) = to_point(pos);
                // A point stays between its neighbours, so the order never changes under the drag.
                let lo = if i > 0 { m.tf.points[i - 1].x } else { 0.0 };
                let hi = m.tf.points.get(i + 1).map_or(1.0, |p| p.x);
                m.tf.points[i].x = x.clamp(lo, hi);
                m.tf.points[i].rgba[3] = a;
                edited(m);
            }
        }
    }
    if response.clicked() {
        if let Some(pos) = response.interact_pointer_pos() {
            match hit(pos) {
                Some(i) => m.selected = Some(i),
                None => {
                    let (x, a) = to_point(pos);
                    let mut rgba = m.tf.sample(x);
                    rgba[3] = a;
                    let at =
                        m.tf.points
                            .iter()
                            .position(|p| p.x > x)
                            .unwrap_or(m.tf.points.len());
                    m.tf.points.insert(at, ControlPoint { x, rgba });
                    m.selected = Some(at);
                    edited(m);
                }
            }
        }
    }
    if response.secondary_clicked() {
        if let Some(i) = response.interact_pointer_pos().and_then(hit) {
            if m.tf.points.len() > 2 {
                m.tf.points.remove(i);
                m.selected = None;
                edited(m);
            }
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

fn importance(ui: &mut egui::Ui, m: &mut Model) {
    use vellum_render::classify::modulation::{
        ApplyTo, ModulateLighting, OpacityModulation, Stipple,
    };
    let md = m.scene.modulation.get_or_insert_with(Modulation::default);
    // Colour (eq. 3, 4).
    let mut on = md.color.is_some();
    if ui.checkbox(&mut on, "colour by ΔD (eq. 3, 4)").changed() {
        md.color = on.then_some(ColorModulation {
            mode: ColorMode::Raw,
            gamma: 1.0,
        });
    }
    if let Some(c) = &mut md.color {
        ui.horizontal(|ui| {
            ui.radio_value(&mut c.mode, ColorMode::Raw, "ΔD (eq. 3)");
            ui.radio_value(&mut c.mode, ColorMode::Abs, "|ΔD| (eq. 4)");
        });
        ui.add(egui::Slider::new(&mut c.gamma, -4.0..=4.0).text("γ"));
        ui.horizontal(|ui| {
            ui.label("adds to");
            ui.radio_value(&mut md.lighting, ModulateLighting::Ambient, "unlit");
            ui.radio_value(&mut md.lighting, ModulateLighting::Phong, "lit");
        });
    }
    // Opacity (eq. 5).
    let mut on = md.opacity.is_some();
    if ui.checkbox(&mut on, "opacity by |ΔD| (eq. 5)").changed() {
        md.opacity = on.then_some(OpacityModulation {
            t_low: 0.1,
            t_high: 1.0,
            k_low: 1.0,
            k_high: 1.0,
        });
    }
    if let Some(o) = &mut md.opacity {
        ui.add(egui::Slider::new(&mut o.t_low, 0.0..=1.0).text("t_l"));
        ui.add(egui::Slider::new(&mut o.t_high, 0.0..=1.0).text("t_h"));
        ui.add(egui::Slider::new(&mut o.k_low, 0.0..=10.0).text("k_l"));
        ui.add(egui::Slider::new(&mut o.k_high, 0.0..=10.0).text("k_h"));
        if o.t_high < o.t_low {
            o.t_high = o.t_low;
        }
    }
    // Stippling (eq. 6).
    let mut on = md.stipple.is_some();
    if ui.checkbox(&mut on, "stipple by |ΔD| (eq. 6)").changed() {
        md.stipple = on.then_some(Stipple {
            t: 0.5,
            f: 1.0,
            seed: 0,
            white: [1.0; 3],
            black: [0.0; 3],
        });
    }
    if let Some(st) = &mut md.stipple {
        ui.add(egui::Slider::new(&mut st.t, 0.0..=1.0).text("t"));
        ui.add(egui::Slider::new(&mut st.f, 0.0..=8.0).text("f"));
        ui.add(egui::Slider::new(&mut st.seed, 0..=99).text("seed"));
        ui.horizontal(|ui| {
            ui.label("colours");
            ui.color_edit_button_rgb(&mut st.white);
            ui.color_edit_button_rgb(&mut st.black);
        });
    }
    if md.is_active() {
        ui.add(egui::Slider::new(&mut md.importance_radius, 1..=16).text("R (voxels)"))
            .on_hover_text("the Gaussian of ΔD = G∗V − V (σ = R/3); a change recomputes ΔD");
        ui.horizontal(|ui| {
            ui.label("levels");
            ui.radio_value(&mut md.apply_to, ApplyTo::Focus, "focus");
            ui.radio_value(&mut md.apply_to, ApplyTo::Context, "context");
            ui.radio_value(&mut md.apply_to, ApplyTo::Both, "both");
        });
    } else {
        // No effect: no modulation in the scene (and no ΔD to compute).
        m.scene.modulation = None;
    }
}

fn renderer(ui: &mut egui::Ui, m: &mut Model) {
    let mut ray = m.scene.raycast.is_some();
    ui.horizontal(|ui| {
        ui.radio_value(&mut ray, false, "slicer");
        ui.radio_value(&mut ray, true, "ray caster");
    });
    match (ray, m.scene.raycast.is_some()) {
        (true, false) => {
            m.scene.raycast = Some(RayOptions {
                jitter: Some(1),
                ..RayOptions::default()
            })
        }
        (false, true) => m.scene.raycast = None,
        _ => {}
    }
    if let Some(r) = &mut m.scene.raycast {
        let mut jitter = r.jitter.is_some();
        if ui.checkbox(&mut jitter, "jitter ray starts").changed() {
            r.jitter = jitter.then_some(1);
        }
        ui.checkbox(&mut r.refine_iso, "refine the isosurface");
    }
    let two_level_possible = m.scene.style.is_none();
    ui.add_enabled(
        two_level_possible,
        egui::Checkbox::new(&mut m.scene.one_pass, "one pass (no levels)"),
    );
    let mut auto = m.scene.slices.is_none();
    ui.checkbox(&mut auto, "slices: two per voxel");
    if auto {
        m.scene.slices = None;
    } else {
        let mut n = m
            .scene
            .slices
            .unwrap_or(2 * *m.dims.iter().max().unwrap_or(&64) as u32);
        ui.add(
            egui::Slider::new(&mut n, 16..=2048)
                .logarithmic(true)
                .text("slices"),
        );
        m.scene.slices = Some(n);
    }
    let l = &mut m.scene.lighting;
    ui.add(egui::Slider::new(&mut l.ambient, 0.0..=1.0).text("ambient"));
    ui.add(egui::Slider::new(&mut l.diffuse, 0.0..=1.0).text("diffuse"));
    ui.add(egui::Slider::new(&mut l.specular, 0.0..=1.0).text("specular"));
    ui.add(egui::Slider::new(&mut l.shininess, 1.0..=128.0).text("shininess"));
    ui.horizontal(|ui| {
        ui.label("background");
        ui.color_edit_button_rgb(&mut m.scene.background);
    });
}

/// The transfer function of the feature map with the hidden features left out (they become
/// transparent), on the volume's normalised range.
pub fn feature_tf(m: &Model) -> vellum_error::Result<TransferFunction> {
    let map = m
        .features
        .as_ref()
        .ok_or_else(|| vellum_error::Error::Invalid("no feature map".into()))?;
    vellum_render::classify::features::feature_transfer_function(
        &visible_map(map, &m.hidden),
        m.range,
    )
}

/// `map` without the features whose labels are in `hidden`.
pub fn visible_map(map: &FeatureMap, hidden: &BTreeSet<String>) -> FeatureMap {
    fn keep(nodes: &mut Vec<Node>, hidden: &BTreeSet<String>) {
        nodes.retain(|n| !matches!(n, Node::Feature(f) if hidden.contains(&f.label)));
        for n in nodes {
            if let Node::Group(g) = n {
                keep(&mut g.children, hidden);
            }
        }
    }
    let mut map = map.clone();
    keep(&mut map.nodes, hidden);
    map
}

/// The hierarchical feature map (FM5): a tree of groups and features, each feature with its
/// visibility, colour and private interval, and the intervals marked on the histogram axis.
fn features(ui: &mut egui::Ui, m: &mut Model) {
    let Some(mut map) = m.features.take() else {
        return;
    };
    let before = (map.clone(), m.hidden.clone());
    feature_axis(ui, m, &map);
    fn tree(
        ui: &mut egui::Ui,
        nodes: &mut [Node],
        hidden: &mut BTreeSet<String>,
        marks: &mut std::collections::BTreeMap<String, Rect>,
    ) {
        for n in nodes {
            match n {
                Node::Group(g) => {
                    egui::CollapsingHeader::new(&g.label)
                        .default_open(true)
                        .show(ui, |ui| tree(ui, &mut g.children, hidden, marks))
                        .header_response
                        .on_hover_text(&g.description);
                }
                Node::Feature(f) => {
                    ui.horizontal(|ui| {
                        let mut visible = !hidden.contains(&f.label);
                        let r = ui.checkbox(&mut visible, "");
                        marks.insert(format!("feature:{}", f.label), r.rect);
                        if r.changed() {
                            if visible {
                                hidden.remove(&f.label);
                            } else {
                                hidden.insert(f.label.clone());
                            }
                        }
                        ui.color_edit_button_rgb(&mut f.color);
                        ui.label(format!(
                            "{}  [{:.4}, {:.4}]",
                            f.label, f.interval[0], f.interval[1]
                        ))
                        .on_hover_text(&f.description);
                    });
                }
            }
        }
    }
    tree(ui, &mut map.nodes, &mut m.hidden, &mut m.marks);
    let changed = before != (map.clone(), m.hidden.clone());
    m.features = Some(map);
    if changed {
        m.features_edited = true;
        match feature_tf(m) {
            Ok(tf) => m.tf = tf,
            Err(e) => m.message = e.to_string(),
        }
    }
}

/// The histogram with each feature's private interval as a band of its colour.
fn feature_axis(ui: &mut egui::Ui, m: &Model, map: &FeatureMap) {
    // Clear of the scroll bar, which appears over the right edge on hover.
    let width = (ui.available_width() - 14.0).max(200.0);
    let (response, painter) = ui.allocate_painter(Vec2::new(width, 60.0), Sense::hover());
    let rect = response.rect;
    painter.rect_filled(rect, 2.0, Color32::from_gray(24));
    histogram(&painter, rect, &m.histogram, true);
    let to_x = |v: f64| {
        let t = ((v - m.range[0]) / (m.range[1] - m.range[0]).max(f64::MIN_POSITIVE)) as f32;
        rect.left() + t.clamp(0.0, 1.0) * rect.width()
    };
    for (_, f) in map.features() {
        let c = f.color.map(|v| (v.clamp(0.0, 1.0) * 255.0) as u8);
        let alpha = if m.hidden.contains(&f.label) { 40 } else { 150 };
        let (x0, x1) = (
            to_x(f.interval[0]),
            to_x(f.interval[1]).max(to_x(f.interval[0]) + 2.0),
        );
        painter.rect_filled(
            Rect::from_min_max(Pos2::new(x0, rect.top()), Pos2::new(x1, rect.bottom())),
            0.0,
            Color32::from_rgba_unmultiplied(c[0], c[1], c[2], alpha),
        );
    }
}

/// The handles of a Gaussian occlusion curve on the spectrum.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum CurveHandle {
    /// The centre, at the mean: up and down move the mean, sideways the whole interval.
    Mean,
    /// Above the centre at mean + width: up and down set the width.
    Width,
    /// The ends of the intensity interval, at the mean.
    Low,
    High,
}

impl CurveHandle {
    const ALL: [CurveHandle; 4] = [
        CurveHandle::Mean,
        CurveHandle::Width,
        CurveHandle::Low,
        CurveHandle::High,
    ];

    /// Where the handle sits, as (intensity, occlusion).
    fn at(self, c: &Curve) -> [f32; 2] {
        let mid = 0.5 * (c.intensity[0] + c.intensity[1]);
        match self {
            CurveHandle::Mean => [mid, c.mean],
            CurveHandle::Width => [mid, (c.mean + c.width).min(1.0)],
            CurveHandle::Low => [c.intensity[0], c.mean],
            CurveHandle::High => [c.intensity[1], c.mean],
        }
    }

    /// Moves the handle of `c` to `p` (intensity, occlusion), keeping the curve valid.
    fn drag(self, c: &mut Curve, p: [f32; 2]) {
        match self {
            CurveHandle::Mean => {
                let half = 0.5 * (c.intensity[1] - c.intensity[0]);
                let mid = p[0].clamp(half, 1.0 - half);
                c.intensity = [mid - half, mid + half];
                c.mean = p[1];
            }
            CurveHandle::Width => c.width = (p[1] - c.mean).clamp(0.005, 1.0),
            CurveHandle::Low => c.intensity[0] = p[0].min(c.intensity[1] - 0.005),
            CurveHandle::High => c.intensity[1] = p[0].max(c.intensity[0] + 0.005),
        }
    }

    fn name(self) -> &'static str {
        match self {
            CurveHandle::Mean => "mean",
            CurveHandle::Width => "width",
            CurveHandle::Low => "low",
            CurveHandle::High => "high",
        }
    }
}

/// The occlusion editor (OS4, OS5): the spectrum (intensity across, occlusion up, log counts)
/// with the OTF's regions and curves over it. Dragging on it tags a rectangle in the brush's
/// colour; the lists edit or delete regions and the decoupled model's Gaussian curves; the AO
/// radius and mapping recompute the occlusion volume.
/// The occlusion editor: the spectrum with the OTF's regions and curves over it (drag a handle
/// to move a curve, drag elsewhere to tag a region), then the regions, the curves, and the AO
/// radius and mapping.
fn occlusion(ui: &mut egui::Ui, m: &mut Model) {
    let Some(mut otf) = m.otf.take() else {
        return;
    };
    let before = otf.clone();
    spectrum_editor(ui, m, &mut otf);
    otf_regions(ui, m, &mut otf);
    ui.separator();
    otf_curves(ui, &mut otf);
    ui.separator();
    occlusion_params(ui, m, &mut otf);
    if otf != before {
        m.otf_edited = true;
    }
    m.otf = Some(otf);
}

/// The spectrum's square on screen: (intensity, occlusion) in [0, 1]² to pixels and back.
struct SpectrumView {
    rect: Rect,
}

impl SpectrumView {
    fn to_screen(&self, s: f32, o: f32) -> Pos2 {
        let r = self.rect;
        Pos2::new(r.left() + s * r.width(), r.bottom() - o * r.height())
    }

    fn to_spectrum(&self, p: Pos2) -> [f32; 2] {
        let r = self.rect;
        [
            ((p.x - r.left()) / r.width()).clamp(0.0, 1.0),
            ((r.bottom() - p.y) / r.height()).clamp(0.0, 1.0),
        ]
    }
}

/// An RGBA colour in [0, 1] as an opaque egui colour.
fn rgb(c: [f32; 4]) -> Color32 {
    let b = |v: f32| (v.clamp(0.0, 1.0) * 255.0) as u8;
    Color32::from_rgb(b(c[0]), b(c[1]), b(c[2]))
}

/// The spectrum image with the OTF drawn over it, and the drags on it.
fn spectrum_editor(ui: &mut egui::Ui, m: &mut Model, otf: &mut OcclusionTf) {
    if m.spectrum_texture.is_none() {
        if let Some(sp) = &m.spectrum {
            m.spectrum_texture = Some(ui.ctx().load_texture(
                "occlusion spectrum",
                spectrum_image(sp),
                egui::TextureOptions::NEAREST,
            ));
        }
    }
    // Clear of the scroll bar, which appears over the right edge on hover.
    let width = (ui.available_width() - 14.0).max(200.0);
    let (response, painter) = ui.allocate_painter(Vec2::new(width, width), Sense::click_and_drag());
    let rect = response.rect;
    m.marks.insert("spectrum".into(), rect);
    match &m.spectrum_texture {
        Some(t) => {
            painter.image(
                t.id(),
                rect,
                Rect::from_min_max(Pos2::ZERO, Pos2::new(1.0, 1.0)),
                Color32::WHITE,
            );
        }
        None => {
            painter.rect_filled(rect, 0.0, Color32::from_gray(24));
        }
    }
    let v = SpectrumView { rect };
    draw_otf(&painter, &v, otf);
    curve_handles(ui, m, &painter, &v, &response, otf);
    tag_region(m, &painter, &v, &response, otf);
}

/// The regions' outlines and the curves' bands.
fn draw_otf(painter: &egui::Painter, v: &SpectrumView, otf: &OcclusionTf) {
    for r in &otf.regions {
        let stroke = Stroke::new(1.5, rgb(r.rgba));
        match &r.shape {
            Shape::Rect {
                intensity,
                occlusion,
            } => {
                let a = v.to_screen(intensity[0], occlusion[1]);
                let b = v.to_screen(intensity[1], occlusion[0]);
                painter.rect_stroke(
                    Rect::from_two_pos(a, b),
                    0.0,
                    stroke,
                    egui::StrokeKind::Middle,
                );
            }
            Shape::Blob { centre, sigma } => {
                let c = v.to_screen(centre[0], centre[1]);
                let radius = Vec2::new(sigma[0] * v.rect.width(), sigma[1] * v.rect.height());
                painter.add(egui::Shape::ellipse_stroke(c, radius, stroke));
            }
        }
    }
    for c in &otf.curves {
        let stroke = Stroke::new(1.5, Color32::from_rgb(120, 220, 255));
        let y = |o: f32| v.to_screen(0.0, o).y;
        painter.line_segment(
            [
                Pos2::new(v.to_screen(c.intensity[0], 0.0).x, y(c.mean)),
                Pos2::new(v.to_screen(c.intensity[1], 0.0).x, y(c.mean)),
            ],
            stroke,
        );
        let band = Rect::from_min_max(
            Pos2::new(
                v.to_screen(c.intensity[0], 0.0).x,
                y((c.mean + c.width).min(1.0)),
            ),
            Pos2::new(
                v.to_screen(c.intensity[1], 0.0).x,
                y((c.mean - c.width).max(0.0)),
            ),
        );
        painter.rect_filled(
            band,
            0.0,
            Color32::from_rgba_unmultiplied(120, 220, 255, 30),
        );
    }
}

/// The curves' handles: drawn over everything, and a drag that starts on one moves it.
fn curve_handles(
    ui: &egui::Ui,
    m: &mut Model,
    painter: &egui::Painter,
    v: &SpectrumView,
    response: &egui::Response,
    otf: &mut OcclusionTf,
) {
    for (i, c) in otf.curves.iter().enumerate() {
        for h in CurveHandle::ALL {
            let [s_, o] = h.at(c);
            let p = v.to_screen(s_, o);
            let active = m.curve_drag == Some((i, h));
            painter.circle(
                p,
                if active { 6.0 } else { 4.5 },
                Color32::from_rgb(120, 220, 255),
                Stroke::new(1.0, Color32::BLACK),
            );
            m.marks.insert(
                format!("curve{}-{}", i + 1, h.name()),
                Rect::from_center_size(p, Vec2::splat(9.0)),
            );
        }
    }
    if response.drag_started() {
        // Where the button went down: egui starts a drag only once the pointer has moved on.
        let origin = ui
            .input(|i| i.pointer.press_origin())
            .or(response.interact_pointer_pos());
        let grab = origin.and_then(|p| {
            let mut best: Option<(f32, (usize, CurveHandle))> = None;
            for (i, c) in otf.curves.iter().enumerate() {
                for h in CurveHandle::ALL {
                    let [s_, o] = h.at(c);
                    let d = v.to_screen(s_, o).distance(p);
                    if d <= 8.0 && best.is_none_or(|(bd, _)| d < bd) {
                        best = Some((d, (i, h)));
                    }
                }
            }
            best.map(|(_, g)| g)
        });
        m.curve_drag = grab;
    }
    if let Some((i, h)) = m.curve_drag {
        if let (Some(c), Some(p)) = (otf.curves.get_mut(i), response.interact_pointer_pos()) {
            h.drag(c, v.to_spectrum(p));
        }
        if response.drag_stopped() || !response.dragged() {
            m.curve_drag = None;
        }
    }
}

/// Tagging: a drag that grabs no handle draws a rectangle, added as a region in the brush's
/// colour (corners in spectrum units; the pointer position is not known on the frame the button
/// is released, so the last one is kept).
fn tag_region(
    m: &mut Model,
    painter: &egui::Painter,
    v: &SpectrumView,
    response: &egui::Response,
    otf: &mut OcclusionTf,
) {
    if response.drag_started() && m.curve_drag.is_none() {
        m.tagging = response
            .interact_pointer_pos()
            .map(|p| [v.to_spectrum(p), v.to_spectrum(p)]);
    }
    if let (Some(t), Some(p)) = (m.tagging.as_mut(), response.interact_pointer_pos()) {
        t[1] = v.to_spectrum(p);
    }
    if let Some([a, b]) = m.tagging {
        let (p0, p1) = (v.to_screen(a[0], a[1]), v.to_screen(b[0], b[1]));
        painter.rect_stroke(
            Rect::from_two_pos(p0, p1),
            0.0,
            Stroke::new(1.0, Color32::WHITE),
            egui::StrokeKind::Middle,
        );
        if response.drag_stopped() || !response.dragged() {
            let (s0, s1) = (a[0].min(b[0]), a[0].max(b[0]));
            let (o0, o1) = (a[1].min(b[1]), a[1].max(b[1]));
            if s1 - s0 > 1e-3 && o1 - o0 > 1e-3 {
                otf.regions.push(Region {
                    shape: Shape::Rect {
                        intensity: [s0, s1],
                        occlusion: [o0, o1],
                    },
                    rgba: m.brush,
                });
            }
            m.tagging = None;
        }
    }
}

/// The brush and the list of regions, each with its colour and a delete button.
fn otf_regions(ui: &mut egui::Ui, m: &mut Model, otf: &mut OcclusionTf) {
    ui.horizontal(|ui| {
        ui.label("brush");
        ui.color_edit_button_rgba_unmultiplied(&mut m.brush);
        ui.label("drag on the spectrum to tag a region");
    });
    let mut delete = None;
    for (i, r) in otf.regions.iter_mut().enumerate() {
        ui.horizontal(|ui| {
            ui.color_edit_button_rgba_unmultiplied(&mut r.rgba);
            ui.label(match &r.shape {
                Shape::Rect {
                    intensity,
                    occlusion,
                } => format!(
                    "rect s {:.2}..{:.2}, o {:.2}..{:.2}",
                    intensity[0], intensity[1], occlusion[0], occlusion[1]
                ),
                Shape::Blob { centre, sigma } => format!(
                    "blob at ({:.2}, {:.2}), σ ({:.2}, {:.2})",
                    centre[0], centre[1], sigma[0], sigma[1]
                ),
            });
            if ui.small_button("delete").clicked() {
                delete = Some(i);
            }
        });
    }
    if let Some(i) = delete {
        otf.regions.remove(i);
    }
}

/// The decoupled model's curves: mean, width and intensity interval each, and a new one.
fn otf_curves(ui: &mut egui::Ui, otf: &mut OcclusionTf) {
    ui.label("Decoupled model: the 1D TF's opacity times Gaussian occlusion curves.");
    let mut delete = None;
    for (i, c) in otf.curves.iter_mut().enumerate() {
        ui.add(egui::Slider::new(&mut c.mean, 0.0..=1.0).text(format!("curve {} mean", i + 1)));
        ui.add(egui::Slider::new(&mut c.width, 0.005..=0.5).text("width"));
        ui.horizontal(|ui| {
            ui.add(
                egui::DragValue::new(&mut c.intensity[0])
                    .range(0.0..=1.0)
                    .speed(0.005)
                    .prefix("s from "),
            );
            ui.add(
                egui::DragValue::new(&mut c.intensity[1])
                    .range(0.0..=1.0)
                    .speed(0.005)
                    .prefix("to "),
            );
            if ui.small_button("delete").clicked() {
                delete = Some(i);
            }
        });
        if c.intensity[1] < c.intensity[0] {
            c.intensity[1] = c.intensity[0];
        }
    }
    if let Some(i) = delete {
        otf.curves.remove(i);
    }
    if ui.button("add a curve").clicked() {
        otf.curves.push(Curve {
            intensity: [0.3, 1.0],
            mean: 0.5,
            width: 0.1,
        });
    }
}

/// The AO radius and mapping, and the button that recomputes the occlusion volume (a spinner
/// while a worker computes it).
fn occlusion_params(ui: &mut egui::Ui, m: &mut Model, otf: &mut OcclusionTf) {
    let (radius, mapping) = (otf.radius, otf.mapping.clone());
    ui.add(egui::Slider::new(&mut otf.radius, 1..=64).text("AO radius (voxels)"));
    egui::ComboBox::from_label("mapping")
        .selected_text(otf.mapping.clone())
        .show_ui(ui, |ui| {
            for name in ["ramp", "gaussian"] {
                ui.selectable_value(&mut otf.mapping, name.to_string(), name);
            }
        });
    if (radius, &mapping) != (otf.radius, &otf.mapping) {
        m.occlusion_params_changed = true;
    }
    let label = if m.occlusion_params_changed {
        "recompute the occlusion (radius or mapping changed)"
    } else {
        "recompute the occlusion"
    };
    match m.occlusion_busy {
        Some(r) => {
            ui.horizontal(|ui| {
                ui.spinner();
                ui.label(format!(
                    "computing the occlusion at R = {r} on a second device…"
                ));
            });
        }
        None => {
            let button = ui.button(label);
            m.marks.insert("recompute-occlusion".into(), button.rect);
            if button.clicked() {
                m.recompute_occlusion = true;
                m.occlusion_params_changed = false;
            }
        }
    }
}

/// The spectrum as an image: log counts in grey, occlusion 0 at the bottom.
fn spectrum_image(sp: &Spectrum) -> egui::ColorImage {
    let [bx, by] = [sp.bins[0] as usize, sp.bins[1] as usize];
    let max = sp.counts.iter().copied().max().unwrap_or(1).max(1) as f32;
    let mut pixels = Vec::with_capacity(bx * by);
    for row in 0..by {
        let o = by - 1 - row;
        for s in 0..bx {
            let c = sp.counts[o * bx + s] as f32;
            let v = ((1.0 + c).ln() / (1.0 + max).ln() * 255.0) as u8;
            pixels.push(Color32::from_gray(v));
        }
    }
    egui::ColorImage::new([bx, by], pixels)
}

/// Bars of a histogram filling `rect`, linear or log.
fn histogram(painter: &egui::Painter, rect: Rect, counts: &[u64], log: bool) {
    let max = counts.iter().copied().max().unwrap_or(1).max(1) as f32;
    let n = counts.len().max(1) as f32;
    for (i, &c) in counts.iter().enumerate() {
        let h = if log {
            (1.0 + c as f32).ln() / (1.0 + max).ln()
        } else {
            c as f32 / max
        };
        let x0 = rect.left() + rect.width() * i as f32 / n;
        let x1 = rect.left() + rect.width() * (i + 1) as f32 / n;
        painter.rect_filled(
            Rect::from_min_max(
                Pos2::new(x0, rect.bottom() - h * rect.height()),
                Pos2::new(x1, rect.bottom()),
            ),
            0.0,
            Color32::from_gray(70),
        );
    }
}
