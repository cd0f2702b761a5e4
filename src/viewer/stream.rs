//! The viewer's side of the brick cache (issue 26): a loader thread that reads and filters the
//! bricks the frames ask for, and the bookkeeping between it, the cache and the frames.
//!
//! Frames draw with what is resident (missing bricks are sampled from coarser levels, and the
//! coarsest level is always there) and ask for what they missed in the feedback buffer. When a
//! frame completes, its requests go to the loader, most asked first, at most [`IN_FLIGHT`] at a
//! time, and the resident bricks they read are marked used; bricks that arrive are given slots
//! (evicting the least recently used ones) and
//! uploaded through the next frame's staging ring, at most [`UPLOADS_PER_FRAME`] a frame, so a
//! frame stays short while the view refines. The feedback buffer is shared by the frames in
//! flight, so what is read after a frame completes may already hold part of the next frame's
//! requests: both are requests of the current view.

use crate::error::{Error, Result};
use crate::passes::paging::Paged;
use crate::volume::bricks::{BrickCache, BrickLevels, BrickTexels, SLOT_BYTES};
use std::collections::HashSet;
use std::sync::{mpsc, Arc};

/// Bricks asked of the loader and not yet uploaded, at most.
pub const IN_FLIGHT: usize = 96;
/// Bricks uploaded per frame, at most.
pub const UPLOADS_PER_FRAME: usize = 24;

/// A loader thread and what is in flight.
pub struct Streamer {
    tx: mpsc::Sender<Vec<usize>>,
    rx: mpsc::Receiver<Result<(usize, BrickTexels)>>,
    in_flight: HashSet<usize>,
    /// Bricks uploaded, and their bytes.
    pub streamed: u64,
    pub streamed_bytes: u64,
}

impl Streamer {
    /// Starts the loader on `levels` and asks it for the coarsest level first.
    pub fn new(levels: Arc<BrickLevels>) -> Self {
        let (tx, jobs) = mpsc::channel::<Vec<usize>>();
        let (done, rx) = mpsc::channel();
        std::thread::spawn(move || {
            for batch in jobs {
                for entry in batch {
                    let texels = levels
                        .key(entry)
                        .ok_or_else(|| Error::Invalid(format!("entry {entry} names no brick")))
                        .and_then(|k| levels.texels(k));
                    if done.send(texels.map(|t| (entry, t))).is_err() {
                        return;
                    }
                }
            }
        });
        Streamer {
            tx,
            rx,
            in_flight: HashSet::new(),
            streamed: 0,
            streamed_bytes: 0,
        }
    }

    /// Asks for the coarsest level of `paged`.
    pub fn start(&mut self, paged: &Paged) {
        self.request(
            paged,
            &BrickCache::pinned_entries(&paged.levels)
                .iter()
                .map(|&e| (e, u32::MAX))
                .collect::<Vec<_>>(),
        );
    }

    /// Asks the loader for the `wanted` entries (with how many rays asked) that are neither
    /// resident nor in flight, most asked first, as far as [`IN_FLIGHT`] allows.
    pub fn request(&mut self, paged: &Paged, wanted: &[(usize, u32)]) {
        let mut order: Vec<(usize, u32)> = wanted
            .iter()
            .copied()
            .filter(|(e, _)| paged.cache.page_table.get(*e) == Some(&0))
            .filter(|(e, _)| !self.in_flight.contains(e))
            .collect();
        order.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
        let room = IN_FLIGHT.saturating_sub(self.in_flight.len());
        let batch: Vec<usize> = order.into_iter().take(room).map(|(e, _)| e).collect();
        if !batch.is_empty() {
            self.in_flight.extend(&batch);
            // A loader that stopped has said why through `rx`.
            let _ = self.tx.send(batch);
        }
    }

    /// The bricks that arrived (at most [`UPLOADS_PER_FRAME`]), given slots in `paged`'s cache:
    /// (slot, texels) to upload with the next frame.
    pub fn arrivals(&mut self, paged: &mut Paged) -> Result<Vec<(usize, BrickTexels)>> {
        let mut got = Vec::new();
        while got.len() < UPLOADS_PER_FRAME {
            match self.rx.try_recv() {
                Ok(r) => got.push(r?),
                Err(mpsc::TryRecvError::Empty) => break,
                Err(mpsc::TryRecvError::Disconnected) => {
                    return Err(Error::Invalid("the brick loader stopped".into()))
                }
            }
        }
        for (e, _) in &got {
            self.in_flight.remove(e);
        }
        let wanted: Vec<(usize, u32)> = got.iter().map(|(e, _)| (*e, 1)).collect();
        let slots = paged.cache.plan(&wanted, got.len());
        let mut texels: std::collections::HashMap<usize, BrickTexels> = got.into_iter().collect();
        let loads: Vec<(usize, BrickTexels)> = slots
            .into_iter()
            .filter_map(|(e, slot)| texels.remove(&e).map(|t| (slot, t)))
            .collect();
        self.streamed += loads.len() as u64;
        self.streamed_bytes += (loads.len() * SLOT_BYTES) as u64;
        Ok(loads)
    }

    /// Bricks asked of the loader and not yet uploaded.
    pub fn requested(&self) -> usize {
        self.in_flight.len()
    }

    /// The corner's line: resident, requested and streamed bricks.
    pub fn status(&self, paged: &Paged) -> String {
        format!(
            "bricks {}/{} resident, {} requested, {} streamed ({:.0} MiB)",
            paged.cache.resident(),
            paged.cache.capacity(),
            self.requested(),
            self.streamed,
            self.streamed_bytes as f64 / (1 << 20) as f64
        )
    }
}
