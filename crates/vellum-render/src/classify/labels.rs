//! Segments from a label volume (issue 42): which segments are drawn, in which colour, and which
//! are the focus level of a two-level frame, as a table of one entry per id the volume holds;
//! and the two buffers the ray caster reads (`raycast.comp`, `LabelVoxels` and `LabelTable`).
//!
//! A sample keeps the opacity its transfer function gives its intensity and takes its
//! segment's colour, which the headlight then shades; a hidden segment's samples add nothing.
//! Id 0 is no segment: its samples keep the transfer function's colour, so the unlabelled
//! tissue around the segments stays visible as the intensity says (a label volume drawn over
//! itself, where that would only outline each segment, hides id 0 instead). With `focus` ids,
//! the segment decides a sample's level instead of the focus interval: those segments are the
//! focus, every other visible sample the context.

use serde::{Deserialize, Serialize};
use std::sync::Arc;
use vellum_error::{Error, Result};
use vellum_gpu::commands::{copy_slice_to_buffer, memory_transition};
use vellum_gpu::{Access, Buffer, BufferDesc, Context, Frame};
use vellum_volume::labels::Labels;

/// The segments of a label volume beside the input, as a scene file and the flags give them.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LabelSpec {
    /// The label volume: a file, a store, or the name of a label image in the input store's
    /// `labels` group.
    pub path: String,
    /// Ids not drawn (`--hide-labels`); 0 hides what no segment holds.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub hide: Vec<u32>,
    /// Ids drawn as the focus level, every other visible one as the context (`--focus-labels`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub focus: Vec<u32>,
    /// Colours that replace the file's or the hashed ones (`--label-colour ID=#RRGGBB`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub colours: Vec<(u32, [u8; 3])>,
}

/// A table entry's flag: the segment is drawn.
pub const SHOWN: u32 = 1;
/// A table entry's flag: the segment is the focus level.
pub const FOCUS: u32 = 2;
/// A table entry's flag: the sample keeps its transfer function's colour (id 0, no segment).
pub const OWN_COLOUR: u32 = 4;
/// A table entry's flag: a hidden segment (not id 0), whose voxels' intensity must not show in
/// the samples that linear filtering blends them into.
pub const SCREENED: u32 = 8;
/// The table's header flag: the segments decide the level (there are focus ids).
pub const LABELS_DECIDE_FOCUS: u32 = 1;

impl LabelSpec {
    /// The ids this spec names that `labels` does not hold, refused in one sentence.
    pub fn check(&self, labels: &Labels) -> Result<()> {
        let named = self
            .hide
            .iter()
            .chain(&self.focus)
            .chain(self.colours.iter().map(|c| &c.0));
        if let Some(id) = named.copied().find(|&id| labels.index_of(id).is_none()) {
            let shown: Vec<String> = labels.ids.iter().take(12).map(|i| i.to_string()).collect();
            let more = if labels.ids.len() > 12 { ", ..." } else { "" };
            return Err(Error::Invalid(format!(
                "label {id} is not in {} (it holds {}{more}); expected one of its ids",
                self.path,
                shown.join(", ")
            )));
        }
        Ok(())
    }

    /// The ray caster's table: the count and the header flags, then per index its colour
    /// (RGBA8, packed as `unpackUnorm4x8` reads it) and its flags. `background`: whether id 0
    /// is drawn (in its transfer function's colour) unless hidden.
    pub fn table(&self, labels: &Labels, background: bool) -> Vec<u32> {
        let mut words = Vec::with_capacity(2 + 2 * labels.ids.len());
        let decide = if self.focus.is_empty() {
            0
        } else {
            LABELS_DECIDE_FOCUS
        };
        words.extend([labels.ids.len() as u32, decide]);
        for &id in &labels.ids {
            let given = self.colours.iter().find(|c| c.0 == id);
            let c = match given {
                Some((_, rgb)) => [rgb[0], rgb[1], rgb[2], 255],
                None => labels.colour(id),
            };
            let shown = (id != 0 || background) && !self.hide.contains(&id);
            let flags = [
                (shown, SHOWN),
                (self.focus.contains(&id), FOCUS),
                (id == 0 && given.is_none(), OWN_COLOUR),
                (id != 0 && !shown, SCREENED),
            ];
            words.push(u32::from_le_bytes(c));
            words.push(flags.iter().filter(|f| f.0).map(|f| f.1).sum());
        }
        words
    }
}

/// A label volume on the GPU: each voxel's index (16 bits, two per word) and the table.
pub struct GpuLabels {
    /// The indices, as `Labels::packed`: beside a volume in core. Through the brick cache each
    /// slot carries its own (`PagedVolume::labels`), and this is `None`.
    pub voxels: Option<Buffer>,
    /// The table, as [`LabelSpec::table`].
    pub table: Buffer,
    /// Whether the segments decide the level (some ids are the focus).
    pub decide_focus: bool,
    /// Whether a segment (not id 0) is hidden: its voxels are then kept out of the samples that
    /// blend them (the ray caster's `LABELS_SCREEN` variant).
    pub screens: bool,
    /// The label volume on the host: ids, counts and colours, for a viewer's list.
    pub labels: Arc<Labels>,
    /// The indices of the segments whose lines a style with lines draws: the focus segments
    /// when there are some, else every drawn one (every id but 0 that is not hidden).
    pub drawn: Vec<u16>,
    /// Per index, the segment's bounding box (first and last voxel), where its lines' field is
    /// written (`Labels::boxes`).
    pub boxes: Vec<[[u32; 3]; 2]>,
    /// The spec the table was made from, and whether id 0 is drawn ([`LabelSpec::table`]).
    spec: LabelSpec,
    background: bool,
    /// A table set since the last frame, uploaded by the next one ([`GpuLabels::record`]).
    pending: Option<Vec<u32>>,
    ctx: Arc<Context>,
}

impl GpuLabels {
    /// `labels` on the GPU as `spec` draws them; `background`: whether id 0 is drawn
    /// ([`LabelSpec::table`]). `in_core`: beside a volume in core, with each voxel's index;
    /// else beside the brick cache, whose slots carry the indices, with the table only.
    pub fn new(
        ctx: &Arc<Context>,
        labels: Arc<Labels>,
        spec: &LabelSpec,
        (background, in_core): (bool, bool),
    ) -> Result<Self> {
        spec.check(&labels)?;
        let voxels = in_core
            .then(|| {
                let words = labels.packed();
                Buffer::storage_from_bytes(ctx, "label voxels", bytemuck::cast_slice(&words))
            })
            .transpose()?;
        // Device-local, written by the frames that record a table ([`GpuLabels::record`]),
        // the first one included.
        let words = spec.table(&labels, background);
        let table = Buffer::new(
            ctx,
            "label table",
            &BufferDesc::storage(4 * words.len() as u64),
        )?;
        Ok(GpuLabels {
            voxels,
            table,
            drawn: drawn(spec, &labels),
            boxes: labels.boxes(),
            decide_focus: !spec.focus.is_empty(),
            screens: screens(spec, &labels),
            labels,
            spec: spec.clone(),
            background,
            pending: Some(words),
            ctx: ctx.clone(),
        })
    }

    /// The spec the segments are drawn by.
    pub fn spec(&self) -> &LabelSpec {
        &self.spec
    }

    /// Whether id 0 is drawn unless hidden ([`LabelSpec::table`]).
    pub fn background(&self) -> bool {
        self.background
    }

    /// Draws the segments as `spec` says from the next frame on (a viewer's edit of visibility,
    /// colour or focus): only the table changes, uploaded when that frame is recorded. An id the
    /// volume lacks is refused and the table kept.
    pub fn set_spec(&mut self, spec: &LabelSpec) -> Result<()> {
        spec.check(&self.labels)?;
        if *spec != self.spec {
            self.pending = Some(spec.table(&self.labels, self.background));
            self.decide_focus = !spec.focus.is_empty();
            self.screens = screens(spec, &self.labels);
            self.drawn = drawn(spec, &self.labels);
            self.spec = spec.clone();
        }
        Ok(())
    }

    /// Records the upload of a table set since the last frame, ordered after the previous
    /// frames' reads and before this one's (`next`).
    pub(crate) fn record(&mut self, frame: &mut Frame, next: Access) -> Result<()> {
        let Some(words) = self.pending.take() else {
            return Ok(());
        };
        let src = frame.staging.push(bytemuck::cast_slice(&words), 16)?;
        memory_transition(&self.ctx, frame.cmd, next, Access::TransferWrite);
        copy_slice_to_buffer(&self.ctx, frame.cmd, &src, &self.table);
        memory_transition(&self.ctx, frame.cmd, Access::TransferWrite, next);
        Ok(())
    }
}

/// Whether `spec` hides a segment `labels` holds (not id 0).
fn screens(spec: &LabelSpec, labels: &Labels) -> bool {
    spec.hide
        .iter()
        .any(|&id| id != 0 && labels.index_of(id).is_some())
}

/// The indices of the segments whose lines a style with lines draws: the focus segments when
/// `spec` names some (the lines belong to the focus level, as the intensity's do), else every
/// segment it draws; id 0 (no segment) apart.
fn drawn(spec: &LabelSpec, labels: &Labels) -> Vec<u16> {
    let id = |i: usize| labels.ids[i];
    (0..labels.ids.len())
        .filter(|&i| id(i) != 0 && !spec.hide.contains(&id(i)))
        .filter(|&i| spec.focus.is_empty() || spec.focus.contains(&id(i)))
        .map(|i| i as u16)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use vellum_volume::{Volume, VoxelData};

    fn labels() -> Labels {
        let v = Volume::new([4, 1, 1], [1.0; 3], VoxelData::U8(vec![0, 3, 7, 3])).unwrap();
        Labels::of_volume(&v, "l").unwrap()
    }

    #[test]
    fn the_table_says_colour_visibility_and_level_per_id() {
        let spec = LabelSpec {
            path: "l".into(),
            hide: vec![7],
            focus: vec![3],
            colours: vec![(3, [10, 20, 30])],
        };
        let t = spec.table(&labels(), true);
        assert_eq!(t[..2], [3, LABELS_DECIDE_FOCUS]);
        assert_eq!(
            t[3],
            SHOWN | OWN_COLOUR,
            "no segment: the TF's colour, context"
        );
        assert_eq!(t[4], u32::from_le_bytes([10, 20, 30, 255]));
        assert_eq!(t[5], SHOWN | FOCUS);
        assert_eq!(
            t[7], SCREENED,
            "7 is hidden, and kept out of the samples around it"
        );
        assert_eq!(LabelSpec::default().table(&labels(), true)[1], 0);
        assert_eq!(
            spec.table(&labels(), false)[3],
            OWN_COLOUR,
            "over itself, 0 is hidden"
        );
    }

    #[test]
    fn an_id_the_volume_lacks_is_one_sentence() {
        let spec = LabelSpec {
            path: "seg.nrrd".into(),
            focus: vec![5],
            ..Default::default()
        };
        let e = spec.check(&labels()).unwrap_err().to_string();
        assert!(
            e.contains("label 5 is not in seg.nrrd (it holds 0, 3, 7)"),
            "{e}"
        );
    }
}
