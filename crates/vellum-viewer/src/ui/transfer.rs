//! The transfer-function panel: presets, the editor drawn over the histogram, and the
//! histogram itself.

use super::*;

pub(super) fn transfer(ui: &mut egui::Ui, m: &mut Model) {
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
pub(super) fn edited(m: &mut Model) {
    m.tf_edited = true;
    m.tf_base = m.tf.clone();
    m.shift = 0.0;
    m.scale = 1.0;
}

pub(super) fn tf_editor(ui: &mut egui::Ui, m: &mut Model) {
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
pub(super) fn draw_tf(painter: &egui::Painter, rect: Rect, m: &Model) -> Vec<Pos2> {
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
pub(super) fn edit_tf(
    ui: &egui::Ui,
    m: &mut Model,
    response: &egui::Response,
    rect: Rect,
    pts: &[Pos2],
) {
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

/// Bars of a histogram filling `rect`, linear or log.
pub(super) fn histogram(painter: &egui::Painter, rect: Rect, counts: &[u64], log: bool) {
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
