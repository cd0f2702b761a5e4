//! The feature-map panel: features listed with their visibility, colour and opacity, and the
//! feature axis.

use super::*;

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
pub(super) fn features(ui: &mut egui::Ui, m: &mut Model) {
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
pub(super) fn feature_axis(ui: &mut egui::Ui, m: &Model, map: &FeatureMap) {
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
