//! The segments panel (issue 42): the ids of a label volume beside the input, each with its
//! visibility, colour, focus and voxel count, and the one picked by a click in the image. The
//! panel edits the scene's `labels` spec (`hide`, `colours`, `focus`), which the session turns
//! into a new label table for the next frame.

use super::*;
use vellum_render::classify::labels::LabelSpec;

/// Most rows the list draws; the rest are reached by picking or by the filter.
const MAX_ROWS: usize = 400;

/// The segments of the label volume on the GPU, as the panel lists them.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Segments {
    /// The ids present, ascending.
    pub ids: Vec<u32>,
    /// Voxels per id.
    pub counts: Vec<u64>,
    /// Each id's colour before the scene's own colours (the file's, or a hash of the id).
    pub colours: Vec<[u8; 3]>,
    /// Whether id 0 is drawn unless hidden (not when the label volume is drawn over itself).
    pub background: bool,
    /// The id the last click picked.
    pub picked: Option<u32>,
    /// Only ids whose number starts with this are listed.
    pub filter: String,
}

impl Segments {
    /// The list of `labels`, drawn with id 0 or not (`background`).
    pub fn of(labels: &vellum_volume::labels::Labels, background: bool) -> Self {
        Segments {
            ids: labels.ids.clone(),
            counts: labels.counts.clone(),
            colours: labels
                .ids
                .iter()
                .map(|&id| {
                    let c = labels.colour(id);
                    [c[0], c[1], c[2]]
                })
                .collect(),
            background,
            picked: None,
            filter: String::new(),
        }
    }

    /// The voxels of `id`.
    pub fn count_of(&self, id: u32) -> u64 {
        self.ids
            .iter()
            .position(|&i| i == id)
            .map_or(0, |k| self.counts[k])
    }
}

/// Whether `spec` draws `id`.
pub fn shown(spec: &LabelSpec, id: u32) -> bool {
    !spec.hide.contains(&id)
}

/// Shows or hides `id` in `spec`.
pub fn set_shown(spec: &mut LabelSpec, id: u32, show: bool) {
    spec.hide.retain(|&h| h != id);
    if !show {
        spec.hide.push(id);
        spec.hide.sort_unstable();
    }
}

/// Puts `id` in the focus level of `spec`, or takes it out.
pub fn set_focus(spec: &mut LabelSpec, id: u32, focus: bool) {
    spec.focus.retain(|&f| f != id);
    if focus {
        spec.focus.push(id);
        spec.focus.sort_unstable();
    }
}

/// The colour `spec` draws `id` in, given its own colour `own`.
pub fn colour_in(spec: &LabelSpec, id: u32, own: [u8; 3]) -> [u8; 3] {
    spec.colours.iter().find(|c| c.0 == id).map_or(own, |c| c.1)
}

/// Gives `id` the colour `rgb` in `spec` (dropped when it is the id's own colour).
pub fn set_colour(spec: &mut LabelSpec, id: u32, rgb: [u8; 3], own: [u8; 3]) {
    spec.colours.retain(|c| c.0 != id);
    if rgb != own {
        spec.colours.push((id, rgb));
        spec.colours.sort_unstable_by_key(|c| c.0);
    }
}

/// The panel: show or hide all, a filter by id, and a row per id (at most [`MAX_ROWS`]): its
/// visibility box (layout mark `label:ID`), colour, focus toggle and voxel count; the picked id
/// first and highlighted.
pub(super) fn segments(ui: &mut egui::Ui, m: &mut Model) {
    let (Some(list), Some(spec)) = (m.segments.as_mut(), m.scene.labels.as_mut()) else {
        return;
    };
    ui.label(format!(
        "{} segments; click the image to pick one. F puts a segment in the focus level, the rest in the context.",
        list.ids.len()
    ));
    ui.horizontal(|ui| {
        if ui.button("show all").clicked() {
            spec.hide.clear();
        }
        if ui.button("hide segments").clicked() {
            spec.hide = list.ids.iter().copied().filter(|&i| i != 0).collect();
        }
        if ui.button("no focus").clicked() {
            spec.focus.clear();
        }
        ui.add(
            egui::TextEdit::singleline(&mut list.filter)
                .hint_text("id")
                .desired_width(60.0),
        );
    });
    let picked = list.picked;
    let order = picked
        .into_iter()
        .chain(list.ids.iter().copied().filter(|&i| Some(i) != picked))
        .filter(|i| i.to_string().starts_with(list.filter.trim()))
        .take(MAX_ROWS);
    let rows: Vec<u32> = order.collect();
    egui::ScrollArea::vertical()
        .max_height(260.0)
        .id_salt("segments")
        .show(ui, |ui| {
            for id in rows {
                segment_row(ui, list, spec, id, &mut m.marks);
            }
        });
}

fn segment_row(
    ui: &mut egui::Ui,
    list: &Segments,
    spec: &mut LabelSpec,
    id: u32,
    marks: &mut std::collections::BTreeMap<String, Rect>,
) {
    let Some(k) = list.ids.iter().position(|&i| i == id) else {
        return;
    };
    ui.horizontal(|ui| {
        let mut visible = shown(spec, id) && (id != 0 || list.background);
        let r = ui.add_enabled(
            id != 0 || list.background,
            egui::Checkbox::new(&mut visible, ""),
        );
        marks.insert(format!("label:{id}"), r.rect);
        if r.changed() {
            set_shown(spec, id, visible);
        }
        let own = list.colours[k];
        let mut rgb = colour_in(spec, id, own);
        if ui.color_edit_button_srgb(&mut rgb).changed() {
            set_colour(spec, id, rgb, own);
        }
        let mut focus = spec.focus.contains(&id);
        if ui
            .toggle_value(&mut focus, "F")
            .on_hover_text("focus level")
            .changed()
        {
            set_focus(spec, id, focus);
        }
        let what = if id == 0 { "no segment, " } else { "" };
        let text = format!("{id:>6}  {what}{} voxels", list.counts[k]);
        match list.picked == Some(id) {
            true => ui.label(egui::RichText::new(text).strong().color(Color32::YELLOW)),
            false => ui.label(text),
        };
    });
}
