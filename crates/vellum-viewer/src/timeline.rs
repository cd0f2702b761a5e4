//! What the session keeps of a store's time points apart from playing them (`playback.rs`): how
//! many there are, how long one stays on screen, and the one read ahead.

use crate::ui::Model;
use std::sync::mpsc;
use std::time::{Duration, Instant};
use vellum_render::classify::transfer::TransferFunction;

/// How long a time point stays on screen while playing, at least, by default: ten a second.
pub(crate) const STEP: Duration = Duration::from_millis(100);

/// When the time point after one shown at `now` is due while playing. A step of the series
/// (`step_of_series`) keeps the clock: one `step` after the shown one was due (`due`), so a frame
/// that lands late does not push every later time point back. When its load made it later than
/// that, the next is due at once and the clock goes on from now: a slow load is not made up for
/// with a burst of time points. Anything else starts the clock again, one step from now.
pub(crate) fn next_due(
    due: Instant,
    now: Instant,
    step: Duration,
    step_of_series: bool,
) -> Instant {
    match step_of_series {
        true => (due + step).max(now),
        false => now + step,
    }
}

/// The step of a play rate in time points per second (`--play-rate`; [`STEP`] for a rate that
/// is not a positive number).
pub(crate) fn step_of(rate: f64) -> Duration {
    match rate.is_finite() && rate > 0.0 {
        true => Duration::from_secs_f64(1.0 / rate),
        false => STEP,
    }
}

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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_playing_clock_keeps_its_rate_through_late_frames() {
        let t0 = Instant::now();
        let ms = Duration::from_millis;
        // Ten a second, each time point shown 30 ms after it was due (a frame's lateness): the
        // next is still due 100 ms after the last was, not 100 ms after it appeared.
        let mut due = t0 + STEP;
        for k in 1..=5u32 {
            let shown = due + ms(30);
            due = next_due(due, shown, STEP, true);
            assert_eq!(due, t0 + STEP * (k + 1));
        }
        // A time point 250 ms late: the next is due at once, and the one after it one step
        // after that (no burst to catch up).
        let shown = due + ms(250);
        assert_eq!(next_due(due, shown, STEP, true), shown);
        assert_eq!(next_due(shown, shown + ms(10), STEP, true), shown + STEP);
        // Another volume opened starts the clock again.
        assert_eq!(next_due(due, shown, STEP, false), shown + STEP);
        assert_eq!(step_of(25.0), ms(40));
        assert_eq!(step_of(0.0), STEP);
        assert_eq!(step_of(f64::NAN), STEP);
    }
}
