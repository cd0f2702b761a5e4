//! Time points of a store in the window: the slider and the play button ask for a time point,
//! which loads on the session's worker like any volume, keeping the scene (transfer function,
//! focus, camera, style). While playing, the next time point is read on a second worker as soon
//! as the current one is shown, so that a step waits only for what is left of its load.

use super::session::{load, Loaded, Session};
use std::sync::mpsc;
use std::time::{Duration, Instant};
use vellum_error::Result;

/// How long a time point stays on screen while playing, at least: ten a second.
pub(crate) const STEP: Duration = Duration::from_millis(100);

/// The next time point, read ahead while the current one plays.
pub(crate) struct Prefetch {
    time: usize,
    answer: mpsc::Receiver<Result<Loaded>>,
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

impl Session {
    /// Shows time point `t`: from the read-ahead when it holds `t`, else loaded now.
    pub(crate) fn show_time(&mut self, t: usize) {
        if t >= self.model.times || (t == self.model.time && !self.loading()) {
            return;
        }
        let what = format!("time point {t}");
        match self.prefetch.take() {
            Some(p) if p.time == t => self.take_over_load(what, p.answer),
            _ => {
                let mut scene = self.model.scene.clone();
                scene.input.time = Some(t);
                self.start_load(what, scene);
            }
        }
    }

    /// Reads time point `t` ahead on a worker of its own.
    pub(crate) fn prefetch(&mut self, t: usize) {
        let mut scene = self.model.scene.clone();
        scene.input.time = Some(t);
        let (tx, rx) = mpsc::channel();
        let budget = self.budget;
        std::thread::spawn(move || {
            let _ = tx.send(load(scene, budget));
        });
        self.prefetch = Some(Prefetch {
            time: t,
            answer: rx,
        });
    }

    /// While playing, the next time point once this one has been shown for [`STEP`] and
    /// nothing is loading; the one after it is read ahead as soon as a time point is shown.
    pub(crate) fn tick_playback(&mut self, now: Instant) {
        let times = self.model.times;
        if !self.model.playing || times < 2 || self.loading() {
            return;
        }
        let next = (self.model.time + 1) % times;
        if self.prefetch.is_none() {
            self.prefetch(next);
        }
        if now >= self.shown_at + STEP {
            self.show_time(next);
        }
    }

    /// Whether the window must keep drawing for the playback.
    pub(crate) fn playing(&self) -> bool {
        self.model.playing && self.model.times > 1
    }
}
