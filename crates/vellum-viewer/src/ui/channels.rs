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

impl ChannelRow {
    /// The rows `new` of another time point of the same channels, carrying over what was set on
    /// `old`: each channel's visibility, and for an edited one its colour and its window in data
    /// units (normalised again to the new time point's range), so that a series plays with the
    /// look it was given. A channel `old` lacks keeps its new row.
    pub fn carried(old: &[ChannelRow], new: Vec<ChannelRow>) -> Vec<ChannelRow> {
        new.into_iter()
            .map(|mut row| {
                let Some(o) = old.iter().find(|o| o.index == row.index) else {
                    return row;
                };
                row.visible = o.visible;
                if o.edited {
                    let ([lo, hi], [nlo, nhi]) = (o.range, row.range);
                    let data = |x: f32| lo + x as f64 * (hi - lo);
                    let norm = |v: f64| {
                        (((v - nlo) / (nhi - nlo).max(f64::MIN_POSITIVE)) as f32).clamp(0.0, 1.0)
                    };
                    row.colour = o.colour;
                    row.window = o.window.map(|x| norm(data(x)));
                    row.edited = true;
                }
                row
            })
            .collect()
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

#[cfg(test)]
mod tests {
    use super::*;

    fn row(index: usize, range: [f64; 2]) -> ChannelRow {
        let tf = ramp([0.0, 1.0, 0.0], [0.0, 1.0]).unwrap();
        ChannelRow {
            index,
            name: None,
            range,
            histogram: vec![0; 256],
            visible: true,
            colour: [0.0, 1.0, 0.0],
            window: [0.0, 1.0],
            loaded: tf,
            edited: false,
        }
    }

    #[test]
    fn a_time_point_keeps_the_channels_look_in_data_units() {
        let mut edited = row(0, [0.0, 100.0]);
        edited.window = [0.25, 0.5];
        edited.colour = [1.0, 0.0, 1.0];
        edited.edited = true;
        let mut hidden = row(1, [0.0, 10.0]);
        hidden.visible = false;
        let old = [edited, hidden];
        let new = vec![
            row(0, [0.0, 200.0]),
            row(1, [0.0, 20.0]),
            row(2, [5.0, 6.0]),
        ];
        let rows = ChannelRow::carried(&old, new.clone());
        // Values 25..50 of the first channel, now over 0..200.
        assert_eq!(rows[0].window, [0.125, 0.25]);
        assert_eq!(rows[0].colour, [1.0, 0.0, 1.0]);
        assert!(rows[0].edited && rows[0].visible);
        assert_eq!(rows[0].range, [0.0, 200.0]);
        // Hidden stays hidden; its window and function are the new time point's.
        assert!(!rows[1].visible && !rows[1].edited);
        assert_eq!(rows[1].window, new[1].window);
        // A channel the old rows lack is as loaded.
        assert_eq!(rows[2], new[2]);
    }
}
