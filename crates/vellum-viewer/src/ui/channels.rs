//! The channels panel (issue 42): the channels of a store mixed in one ray, each with its
//! visibility, colour and window over a histogram of its values. An edit makes the channel's
//! transfer function a ramp in its colour across its window (transparent when hidden), which
//! the session sends to the GPU state as the channels' new functions.

use super::*;
use vellum_render::classify::channels::{ramp, ChannelInfo};

/// One mixed channel as the panel edits it.
#[derive(Clone, Debug, PartialEq)]
pub struct ChannelRow {
    /// Its index in the store and its NGFF name.
    pub index: usize,
    pub name: Option<String>,
    /// The values its function spans, and 256 bins of its voxels over them.
    pub range: [f64; 2],
    pub histogram: Vec<u64>,
    /// Drawn or not.
    pub visible: bool,
    /// Its colour, and the window its opacity rises across (normalised to `range`).
    pub colour: [f32; 3],
    pub window: [f32; 2],
    /// Its function as loaded, kept until the row is edited (a file's may be no ramp).
    pub loaded: TransferFunction,
    /// Whether colour or window were edited (the function is then the row's ramp).
    pub edited: bool,
}

impl ChannelRow {
    /// The row of a channel as the GPU state holds it: its colour from the function's opaque
    /// end, its window from where its opacity starts rising to where it is full.
    pub fn of(info: &ChannelInfo) -> Self {
        let pts = &info.tf.points;
        let top = pts.iter().map(|p| p.rgba[3]).fold(0.0f32, f32::max);
        let rise = pts.iter().position(|p| p.rgba[3] > 0.0).unwrap_or(0);
        let lo = pts[rise.saturating_sub(1)].x;
        let full = pts.iter().find(|p| p.rgba[3] >= top).map_or(1.0, |p| p.x);
        let c = pts.last().map_or([1.0; 4], |p| p.rgba);
        ChannelRow {
            index: info.index,
            name: info.name.clone(),
            range: info.range,
            histogram: info.histogram.clone(),
            visible: true,
            colour: [c[0], c[1], c[2]],
            window: [lo, full.max(lo)],
            loaded: info.tf.clone(),
            edited: false,
        }
    }

    /// The function the row draws with: none (transparent) when hidden, the loaded one until
    /// edited, else a ramp in its colour across its window.
    pub fn tf(&self) -> vellum_error::Result<TransferFunction> {
        let [r, g, b] = self.colour;
        let clear = |x: f32| ControlPoint {
            x,
            rgba: [r, g, b, 0.0],
        };
        match (self.visible, self.edited) {
            (false, _) => TransferFunction::new("hidden", vec![clear(0.0), clear(1.0)]),
            (true, false) => Ok(self.loaded.clone()),
            (true, true) => ramp(self.colour, self.window),
        }
    }
}

/// The panel: per channel, its visibility box (layout mark `channel:INDEX`), colour, name, its
/// window in data units, and its histogram with the window marked.
pub(super) fn channels(ui: &mut egui::Ui, m: &mut Model) {
    let Some(rows) = m.channels.as_mut() else {
        return;
    };
    ui.label("Each channel's opacity rises across its window, in its colour.");
    for row in rows.iter_mut() {
        ui.horizontal(|ui| {
            let r = ui.checkbox(&mut row.visible, "");
            m.marks.insert(format!("channel:{}", row.index), r.rect);
            if ui.color_edit_button_rgb(&mut row.colour).changed() {
                row.edited = true;
            }
            let name = row.name.as_deref().unwrap_or("");
            ui.label(format!("channel {} {name}", row.index));
        });
        let [lo, hi] = row.range;
        let data = |x: f32| lo + x as f64 * (hi - lo);
        let mut w = row.window.map(data);
        let a = ui.add(egui::Slider::new(&mut w[0], lo..=hi).text("from"));
        let b = ui.add(egui::Slider::new(&mut w[1], lo..=hi).text("to"));
        if a.changed() || b.changed() {
            let norm = |v: f64| ((v - lo) / (hi - lo).max(f64::MIN_POSITIVE)) as f32;
            row.window = [norm(w[0]), norm(w[1]).max(norm(w[0]))];
            row.edited = true;
        }
        channel_histogram(ui, row);
    }
}

/// The channel's histogram (log counts) in its colour, with its window shaded.
fn channel_histogram(ui: &mut egui::Ui, row: &ChannelRow) {
    let (rect, _) = ui.allocate_exact_size(Vec2::new(ui.available_width(), 40.0), Sense::hover());
    let p = ui.painter_at(rect);
    p.rect_filled(rect, 0.0, Color32::from_gray(20));
    let x = |f: f32| rect.left() + f * rect.width();
    let [a, b] = row.window;
    p.rect_filled(
        Rect::from_min_max(Pos2::new(x(a), rect.top()), Pos2::new(x(b), rect.bottom())),
        0.0,
        Color32::from_gray(45),
    );
    let top = row
        .histogram
        .iter()
        .map(|&c| (c as f32 + 1.0).ln())
        .fold(1.0, f32::max);
    let [r, g, bl] = row.colour.map(|c| (c * 255.0) as u8);
    let n = row.histogram.len().max(1) as f32;
    for (i, &c) in row.histogram.iter().enumerate() {
        let h = (c as f32 + 1.0).ln() / top * rect.height();
        let x0 = x(i as f32 / n);
        p.line_segment(
            [
                Pos2::new(x0, rect.bottom()),
                Pos2::new(x0, rect.bottom() - h),
            ],
            Stroke::new(1.0, Color32::from_rgb(r, g, bl)),
        );
    }
}
