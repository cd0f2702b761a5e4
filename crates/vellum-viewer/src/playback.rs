//! Time points of a store in the window: the slider and the play button ask for a time point,
//! which loads on the session's worker like any volume, keeping the scene (transfer function,
//! focus, camera, style). While playing, the next time point is read on a second worker as soon
//! as the current one is shown, so that a step waits only for what is left of its load.

use super::session::{Loaded, Session};
use super::timeline::Prefetch;
use crate::loading::load_time_point;
use std::sync::mpsc;
use std::time::Instant;
use vellum_error::Result;

impl Session {
    /// A store of several time points is drawn on the scale of the first one shown, and with
    /// its `auto` line smoothing: later ones load with them (`input.range`,
    /// `input.line_smooth`).
    pub(crate) fn fix_series_scale(&mut self) {
        if self.model.times > 1 && self.model.scene.input.range.is_none() {
            let smooth = vellum_volume::lines::auto_smooth_radius(&self.volume);
            for input in [&mut self.model.scene.input, &mut self.applied.input] {
                input.range = Some(self.model.range);
                input.line_smooth = Some(smooth);
            }
        }
    }

    /// The channels of a store of several time points are drawn on the scales of the first
    /// time point shown, each with the function it loaded with there: later ones load with them
    /// (`channels.scales`), so an unedited channel keeps one scale through the series.
    pub(crate) fn fix_channel_scales(&mut self) {
        let Some(rows) = self
            .model
            .channels
            .as_ref()
            .filter(|_| self.model.times > 1)
        else {
            return;
        };
        let scales: Vec<_> = rows
            .iter()
            .map(|r| vellum_render::classify::channels::ChannelScale {
                channel: r.index,
                range: r.range,
                tf: r.loaded.clone(),
            })
            .collect();
        for scene in [&mut self.model.scene, &mut self.applied] {
            if let Some(spec) = scene.channels.as_mut().filter(|s| s.scales.is_empty()) {
                spec.scales = scales.clone();
            }
        }
    }

    /// Shows time point `t`: from the read-ahead when it holds `t`, else loaded now.
    pub(crate) fn show_time(&mut self, t: usize) {
        if t >= self.model.times || (t == self.model.time && !self.loading()) {
            return;
        }
        if self.ready == Some(t) && !self.loading() {
            // On the GPU already: the shell swaps it in.
            self.swap = true;
            return;
        }
        let what = format!("time point {t}");
        match self.prefetch.take() {
            Some(p) if p.time == t => self.take_over_load(what, p.answer),
            _ => {
                let answer = self.read_time_point(t);
                self.take_over_load(what, answer);
            }
        }
    }

    /// Reads time point `t` on a worker of its own, with the scene and transfer function kept.
    fn read_time_point(&self, t: usize) -> mpsc::Receiver<Result<Loaded>> {
        let mut scene = self.model.scene.clone();
        scene.input.time = Some(t);
        let (tx, rx) = mpsc::channel();
        let (budget, look) = (self.budget.clone(), self.model.tf.clone());
        std::thread::spawn(move || {
            let _ = tx.send(load_time_point(scene, &budget, look));
        });
        rx
    }

    /// Reads time point `t` ahead on a worker of its own.
    pub(crate) fn prefetch(&mut self, t: usize) {
        let answer = self.read_time_point(t);
        self.prefetch = Some(Prefetch { time: t, answer });
    }

    /// Once time point `t` has been read ahead, the one after it is read meanwhile (unless it
    /// is the one shown): its read overlaps `t`'s upload and normals on the thread that draws.
    pub(crate) fn prefetch_after(&mut self, t: usize) {
        let next = (t + 1) % self.model.times.max(1);
        if self.prefetch.is_none() && next != self.model.time && next != t {
            self.prefetch(next);
        }
    }

    /// While playing, the next time point once it is due (`due_at`: one step, at most the play
    /// rate, after this one was) and nothing is loading; the one after it is read ahead as soon as a time point is shown, and
    /// the one after that once the shell holds the next on the GPU.
    pub(crate) fn tick_playback(&mut self, now: Instant) {
        let times = self.model.times;
        if !self.model.playing || times < 2 || self.loading() {
            return;
        }
        let next = (self.model.time + 1) % times;
        // With the next one on the GPU already, the one after it is read meanwhile.
        let want = match self.ready == Some(next) {
            true => (next + 1) % times,
            false => next,
        };
        if self.prefetch.is_none() && self.ready != Some(want) && want != self.model.time {
            self.prefetch(want);
        }
        if now >= self.due_at {
            self.show_time(next);
        }
    }

    /// The time point read ahead, once its worker has answered (the shell puts it on the GPU).
    pub(crate) fn take_prefetched(&mut self) -> Option<(usize, Result<Loaded>)> {
        let p = self.prefetch.as_ref()?;
        let got = match p.answer.try_recv() {
            Ok(got) => got,
            Err(mpsc::TryRecvError::Empty) => return None,
            Err(mpsc::TryRecvError::Disconnected) => Err(vellum_error::Error::Invalid(
                "the loader stopped without an answer".into(),
            )),
        };
        let t = p.time;
        self.prefetch = None;
        Some((t, got))
    }

    /// Whether the window must keep drawing for the playback.
    pub(crate) fn playing(&self) -> bool {
        self.model.playing && self.model.times > 1
    }
}
