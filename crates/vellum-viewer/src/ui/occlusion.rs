//! The occlusion panel: the spectrum editor (regions and curves over the intensity ×
//! occlusion histogram) and the occlusion volume's parameters.

use super::*;

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
pub(super) fn occlusion(ui: &mut egui::Ui, m: &mut Model) {
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
pub(super) struct SpectrumView {
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
pub(super) fn rgb(c: [f32; 4]) -> Color32 {
    let b = |v: f32| (v.clamp(0.0, 1.0) * 255.0) as u8;
    Color32::from_rgb(b(c[0]), b(c[1]), b(c[2]))
}

/// The spectrum image with the OTF drawn over it, and the drags on it.
pub(super) fn spectrum_editor(ui: &mut egui::Ui, m: &mut Model, otf: &mut OcclusionTf) {
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
pub(super) fn draw_otf(painter: &egui::Painter, v: &SpectrumView, otf: &OcclusionTf) {
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
pub(super) fn curve_handles(
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
pub(super) fn tag_region(
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
pub(super) fn otf_regions(ui: &mut egui::Ui, m: &mut Model, otf: &mut OcclusionTf) {
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
pub(super) fn otf_curves(ui: &mut egui::Ui, otf: &mut OcclusionTf) {
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
pub(super) fn occlusion_params(ui: &mut egui::Ui, m: &mut Model, otf: &mut OcclusionTf) {
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
pub(super) fn spectrum_image(sp: &Spectrum) -> egui::ColorImage {
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
