//! What the session keeps of a store's time points apart from playing them (`playback.rs`): how
//! many there are, how long one stays on screen, and the one read ahead.

use crate::ui::Model;
use std::sync::mpsc;
use std::time::Duration;
use vellum_render::classify::transfer::TransferFunction;

/// How long a time point stays on screen while playing, at least: ten a second.
pub(crate) const STEP: Duration = Duration::from_millis(100);

/// The next time point, read ahead while the current one plays: its index and the worker's
/// answer (a loaded volume).
pub(crate) struct Prefetch<T> {
    pub(crate) time: usize,
    pub(crate) answer: mpsc::Receiver<T>,
}

/// How many time points the input of `scene` has: a store's t axis, else 1. Only the metadata is
/// read.
pub(crate) fn times_of(scene: &vellum_render::render::scene::Scene) -> usize {
    use vellum_volume::io::ome_zarr::{self, Multiscale, Pick};
    let path = std::path::Path::new(&scene.input.path);
    if scene.input.raw.is_some() || !ome_zarr::is_store(path) {
        return 1;
    }
    let pick = Pick {
        time: Some(0),
        channel: Some(scene.input.channel.unwrap_or(0)),
    };
    Multiscale::open_picked(path, pick).map_or(1, |ms| ms.times)
}

/// What a series keeps from one time point to the next: the transfer function as edited, with
/// its window, and the histogram it is edited over.
pub(crate) struct SeriesLook {
    tf: TransferFunction,
    tf_base: TransferFunction,
    tf_edited: bool,
    shift: f32,
    scale: f32,
    histogram: Vec<u64>,
}

impl SeriesLook {
    pub(crate) fn of(m: &Model) -> Self {
        SeriesLook {
            tf: m.tf.clone(),
            tf_base: m.tf_base.clone(),
            tf_edited: m.tf_edited,
            shift: m.shift,
            scale: m.scale,
            histogram: m.histogram.clone(),
        }
    }

    pub(crate) fn restore(self, m: &mut Model) {
        m.tf = self.tf;
        m.tf_base = self.tf_base;
        m.tf_edited = self.tf_edited;
        m.shift = self.shift;
        m.scale = self.scale;
        m.histogram = self.histogram;
    }
}
