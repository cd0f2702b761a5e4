//! The `--bench` orbit's bookkeeping: frame times, per-pass GPU times and the process's resident
//! memory. It is bounded whatever the number of frames: times are kept for the last [`WINDOW`]
//! frames, pass names once, and one memory sample every [`RSS_EVERY`] frames. That is what lets
//! a 20,000-frame soak show that the viewer itself holds its memory flat.

use std::collections::VecDeque;

/// Frames whose times a report is taken over (the last ones).
pub const WINDOW: usize = 4096;
/// The first frames compile pipelines and fill caches: their times are left out.
const WARM_UP: u64 = 5;
/// The resident memory is sampled every this many presented frames.
pub const RSS_EVERY: u64 = 1000;

/// Frame times of a `--bench` orbit.
#[derive(Clone, Debug, serde::Serialize)]
pub struct BenchReport {
    /// The device the window rendered on.
    pub device: String,
    /// The input viewed.
    pub input: String,
    /// The volume view in window pixels.
    pub size: [u32; 2],
    /// "interactive" (adaptive quality while the camera moves) or "full".
    pub quality: &'static str,
    /// The size the volume was rendered at (the view's, or half of it while interacting).
    pub render_size: [u32; 2],
    /// Frames the figures below are taken over: the last 4,096 (`WINDOW`) after the warm-up.
    pub frames: usize,
    /// Frames presented in all.
    pub frames_presented: u64,
    /// Frames presented per second of wall time.
    pub fps: f64,
    /// The median frame time in milliseconds.
    pub p50_ms: f64,
    /// The 95th percentile of the frame times.
    pub p95_ms: f64,
    /// The 99th percentile of the frame times.
    pub p99_ms: f64,
    /// Median GPU ms per pass over the same frames.
    pub gpu_ms: Vec<(String, f64)>,
    /// (frames presented, resident set in KiB), every 1,000 frames (Linux only).
    pub rss_kib: Vec<(u64, u64)>,
    /// (frames presented, bytes of Rust heap live), every 1,000 frames, where the binary counts
    /// them (`memory::Counting`): what vellum keeps, without the driver's and the layer's.
    pub heap_bytes: Vec<(u64, u64)>,
    /// Milliseconds from opening the window's context to the first frame presented.
    pub first_frame_ms: Option<f64>,
    /// The brick cache's line at the end, when the volume is streamed.
    pub streaming: Option<String>,
    /// Time points of a store shown while playing (`--play`), each loaded and drawn.
    pub time_points_shown: u64,
    /// Time points shown per second, from the first step to the last.
    pub time_points_per_s: Option<f64>,
    /// Every frame's figures, warm-up included, when the log keeps them (`--bench-log`).
    #[serde(skip)]
    pub rows: Vec<FrameRow>,
}

/// One figure of one frame, as `view --bench-log` writes it: `present` rows give the time since
/// the frame before (`frame_ms`), `gpu` rows a pass's GPU ms, and `bricks` rows the bricks the
/// frame's rays asked for (`asked`) and the resident ones they read (`read`). Presented and
/// completed frames are counted apart: with frames in flight, a frame completes after others
/// are presented.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameRow {
    /// `present`, `gpu` or `bricks`.
    pub kind: &'static str,
    /// The frame's number among those presented (`present`) or completed (`gpu`, `bricks`),
    /// from 1.
    pub frame: u64,
    /// The figure's name: `frame_ms`, a pass's, `asked` or `read`.
    pub name: String,
    /// Its value.
    pub value: f64,
}

impl FrameRow {
    /// The rows as CSV, with a header line.
    pub fn write_csv(rows: &[FrameRow], w: &mut impl std::io::Write) -> std::io::Result<()> {
        writeln!(w, "kind,frame,name,value")?;
        for r in rows {
            writeln!(w, "{},{},{},{}", r.kind, r.frame, r.name, r.value)?;
        }
        Ok(())
    }
}

/// What the report is made of, gathered frame by frame.
pub struct BenchLog {
    /// Orbit steps still to take.
    pub left: u32,
    /// Whether the orbit renders at full resolution.
    pub full: bool,
    presented: u64,
    completed: u64,
    frame_ms: VecDeque<f64>,
    /// Per pass name, its times over the last frames that ran it: a steady frame allocates
    /// nothing here.
    gpu: Vec<(String, VecDeque<f64>)>,
    rss_kib: Vec<(u64, u64)>,
    heap_bytes: Vec<(u64, u64)>,
    /// Time points shown while playing, and when the first and the last were.
    time_points: u64,
    time_span: Option<(std::time::Instant, std::time::Instant)>,
    /// Every frame's figures, kept only when asked ([`BenchLog::keeping_rows`]): a bench of N
    /// frames keeps a few rows per frame.
    rows: Option<Vec<FrameRow>>,
}

impl BenchLog {
    /// A log for an orbit of `frames` steps.
    pub fn new(frames: u32, full: bool) -> Self {
        BenchLog {
            left: frames,
            full,
            presented: 0,
            completed: 0,
            frame_ms: VecDeque::with_capacity(WINDOW),
            gpu: Vec::new(),
            rss_kib: Vec::new(),
            heap_bytes: Vec::new(),
            time_points: 0,
            time_span: None,
            rows: None,
        }
    }

    /// The log `opts` asks for: none without `--bench`, rows kept with `--bench-log`.
    pub fn of_view(opts: &crate::ViewOptions) -> Option<Self> {
        let log = BenchLog::new(opts.bench_frames?, opts.bench_full);
        Some(if opts.bench_rows {
            log.keeping_rows()
        } else {
            log
        })
    }

    /// The same log, keeping every frame's figures for the report's `rows`.
    pub fn keeping_rows(mut self) -> Self {
        self.rows = Some(Vec::new());
        self
    }

    fn row(&mut self, kind: &'static str, frame: u64, name: &str, value: f64) {
        if let Some(rows) = &mut self.rows {
            rows.push(FrameRow {
                kind,
                frame,
                name: name.to_string(),
                value,
            });
        }
    }

    /// The rays of the last completed frame asked for `asked` missing bricks and read `read`
    /// resident ones.
    pub fn streamed(&mut self, asked: usize, read: usize) {
        let frame = self.completed;
        self.row("bricks", frame, "asked", asked as f64);
        self.row("bricks", frame, "read", read as f64);
    }

    /// Another time point is on screen (playing), at `now`.
    pub fn time_point_shown(&mut self, now: std::time::Instant) {
        self.time_points += 1;
        let first = self.time_span.map_or(now, |s| s.0);
        self.time_span = Some((first, now));
    }

    /// A frame was presented `ms` after the one before it.
    pub fn presented(&mut self, ms: f64) {
        self.presented += 1;
        self.row("present", self.presented, "frame_ms", ms);
        if self.presented > WARM_UP {
            push_bounded(&mut self.frame_ms, ms);
        }
        if self.presented.is_multiple_of(RSS_EVERY) {
            if let Some(kib) = resident_kib() {
                self.rss_kib.push((self.presented, kib));
            }
            if let Some(bytes) = vellum_volume::memory::live_heap_bytes() {
                self.heap_bytes.push((self.presented, bytes));
            }
        }
    }

    /// A frame completed on the GPU with these pass times.
    pub fn completed(&mut self, passes: &[vellum_gpu::PassTime]) {
        self.completed += 1;
        for p in passes {
            self.row("gpu", self.completed, &p.name, p.ms);
        }
        if self.completed <= WARM_UP {
            return;
        }
        for p in passes {
            let i = match self.gpu.iter().position(|(n, _)| *n == p.name) {
                Some(i) => i,
                None => {
                    self.gpu
                        .push((p.name.clone(), VecDeque::with_capacity(WINDOW)));
                    self.gpu.len() - 1
                }
            };
            push_bounded(&mut self.gpu[i].1, p.ms);
        }
    }

    /// The frame-time percentiles and median pass times; the caller fills in what the log does
    /// not know (device, input, sizes).
    pub fn report(&self, base: BenchReport) -> BenchReport {
        let mut ms: Vec<f64> = self.frame_ms.iter().copied().collect();
        ms.sort_by(f64::total_cmp);
        let pct = |p: f64| match ms.len() {
            0 => f64::NAN,
            n => ms[((p * (n - 1) as f64).round() as usize).min(n - 1)],
        };
        // Passes of the warm-up frames only (a one-off smoothing) have no figure to report.
        let gpu_ms = self
            .gpu
            .iter()
            .filter_map(|(name, times)| {
                let mut v: Vec<f64> = times.iter().copied().collect();
                v.sort_by(f64::total_cmp);
                v.get(v.len() / 2).map(|&med| (name.clone(), med))
            })
            .collect();
        let mean = ms.iter().sum::<f64>() / ms.len().max(1) as f64;
        BenchReport {
            frames: ms.len(),
            frames_presented: self.presented,
            fps: 1e3 / mean,
            p50_ms: pct(0.5),
            p95_ms: pct(0.95),
            p99_ms: pct(0.99),
            gpu_ms,
            rss_kib: self.rss_kib.clone(),
            heap_bytes: self.heap_bytes.clone(),
            time_points_shown: self.time_points,
            // Steps between the first time point shown and the last, over the time they took.
            time_points_per_s: self.time_span.and_then(|(a, b)| {
                let s = (b - a).as_secs_f64();
                (self.time_points > 1 && s > 0.0).then(|| (self.time_points - 1) as f64 / s)
            }),
            rows: self.rows.clone().unwrap_or_default(),
            ..base
        }
    }
}

/// Appends `value`, dropping the oldest once [`WINDOW`] are kept.
fn push_bounded<T>(q: &mut VecDeque<T>, value: T) {
    if q.len() == WINDOW {
        q.pop_front();
    }
    q.push_back(value);
}

/// The process's resident set in KiB (`VmRSS` of /proc/self/status), where the system has one.
pub fn resident_kib() -> Option<u64> {
    vellum_volume::memory::resident_kib()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn base() -> BenchReport {
        BenchReport {
            device: String::new(),
            input: String::new(),
            size: [0, 0],
            quality: "full",
            render_size: [0, 0],
            frames: 0,
            frames_presented: 0,
            fps: 0.0,
            p50_ms: 0.0,
            p95_ms: 0.0,
            p99_ms: 0.0,
            gpu_ms: Vec::new(),
            rss_kib: Vec::new(),
            heap_bytes: Vec::new(),
            first_frame_ms: None,
            streaming: None,
            time_points_shown: 0,
            time_points_per_s: None,
            rows: Vec::new(),
        }
    }

    #[test]
    fn rows_are_kept_only_when_asked_and_written_as_csv() {
        let pass = vec![vellum_gpu::PassTime {
            name: "raycast".into(),
            ms: 2.5,
        }];
        let run = |log: &mut BenchLog| {
            log.presented(16.0);
            log.completed(&pass);
            log.streamed(3, 7);
            log.report(base()).rows
        };
        assert!(run(&mut BenchLog::new(1, false)).is_empty());
        let rows = run(&mut BenchLog::new(1, false).keeping_rows());
        let mut csv = Vec::new();
        FrameRow::write_csv(&rows, &mut csv).unwrap();
        assert_eq!(
            String::from_utf8(csv).unwrap(),
            "kind,frame,name,value\npresent,1,frame_ms,16\ngpu,1,raycast,2.5\n\
             bricks,1,asked,3\nbricks,1,read,7\n"
        );
    }

    #[test]
    fn the_log_keeps_a_window_and_skips_the_warm_up() {
        let mut log = BenchLog::new(10, false);
        let pass = |ms: f64| {
            vec![vellum_gpu::PassTime {
                name: "raycast".into(),
                ms,
            }]
        };
        // Warm-up frames are slow and must not show.
        for _ in 0..WARM_UP {
            log.presented(1000.0);
            log.completed(&pass(500.0));
        }
        for i in 0..(WINDOW + 100) {
            let ms = if i < 100 { 50.0 } else { 10.0 };
            log.presented(ms);
            log.completed(&pass(ms / 10.0));
        }
        let r = log.report(base());
        assert_eq!(r.frames, WINDOW);
        assert_eq!(r.frames_presented, WARM_UP + WINDOW as u64 + 100);
        // Only the last WINDOW frames count: the 100 slow ones have left the window.
        assert_eq!((r.p50_ms, r.p99_ms), (10.0, 10.0));
        assert_eq!(r.gpu_ms, vec![("raycast".to_string(), 1.0)]);
        assert!(log.frame_ms.len() <= WINDOW && log.gpu[0].1.len() <= WINDOW);
        assert_eq!(log.gpu.len(), 1);
        if resident_kib().is_some() {
            assert_eq!(r.rss_kib.len() as u64, r.frames_presented / RSS_EVERY);
            assert_eq!(r.rss_kib[0].0, RSS_EVERY);
        }
    }
}
