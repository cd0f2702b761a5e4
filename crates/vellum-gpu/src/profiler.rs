//! Per-pass GPU timing with timestamp queries. A pass is opened with [`Profiler::begin`] and closed
//! with [`Profiler::end`]; both also open and close a debug label of the same name, so captures and
//! timings use the same names. Results are milliseconds by pass name, read after the submission.
//!
//! Timestamps are written at `ALL_COMMANDS`: the begin stamp lands once earlier work has finished,
//! so a pass's time does not include the tail of the pass before it.

use crate::context::Context;
use crate::VkContext;
use ash::vk;
use std::sync::Arc;
use vellum_error::Result;

/// One timed pass.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct PassTime {
    /// The pass, as its debug label names it.
    pub name: String,
    /// GPU milliseconds from its first to its last command.
    pub ms: f64,
}

/// Timestamp query pool for up to `capacity` passes per submission.
pub struct Profiler {
    ctx: Arc<Context>,
    pool: vk::QueryPool,
    capacity: u32,
    names: Vec<String>,
    open: bool,
}

impl Profiler {
    /// A profiler for up to `capacity` passes per recording.
    pub fn new(ctx: &Arc<Context>, capacity: u32) -> Result<Self> {
        let info = vk::QueryPoolCreateInfo::default()
            .query_type(vk::QueryType::TIMESTAMP)
            .query_count(capacity * 2);
        let pool = unsafe { ctx.device.create_query_pool(&info, None) }
            .vk("creating the timestamp query pool")?;
        ctx.set_name(pool, "profiler");
        Ok(Profiler {
            ctx: ctx.clone(),
            pool,
            capacity,
            names: Vec::new(),
            open: false,
        })
    }

    /// Starts a new recording: resets the queries and forgets earlier pass names.
    pub(crate) fn reset(&mut self, cmd: vk::CommandBuffer) {
        unsafe {
            self.ctx
                .device
                .cmd_reset_query_pool(cmd, self.pool, 0, self.capacity * 2)
        };
        self.names.clear();
        self.open = false;
    }

    /// Opens pass `name`: a debug label and the begin timestamp.
    pub fn begin(&mut self, cmd: vk::CommandBuffer, name: &str) {
        assert!(
            !self.open,
            "profiler pass {name} opened inside another pass"
        );
        assert!(
            (self.names.len() as u32) < self.capacity,
            "profiler capacity {} exceeded",
            self.capacity
        );
        let q = self.names.len() as u32 * 2;
        self.ctx.begin_label(cmd, name);
        unsafe {
            self.ctx.device.cmd_write_timestamp2(
                cmd,
                vk::PipelineStageFlags2::ALL_COMMANDS,
                self.pool,
                q,
            )
        };
        self.names.push(name.to_string());
        self.open = true;
    }

    /// Closes the open pass.
    pub fn end(&mut self, cmd: vk::CommandBuffer) {
        assert!(self.open, "profiler end without begin");
        let q = (self.names.len() as u32 - 1) * 2 + 1;
        unsafe {
            self.ctx.device.cmd_write_timestamp2(
                cmd,
                vk::PipelineStageFlags2::ALL_COMMANDS,
                self.pool,
                q,
            )
        };
        self.ctx.end_label(cmd);
        self.open = false;
    }

    /// Records `body` as pass `name`.
    pub fn pass<R>(
        &mut self,
        cmd: vk::CommandBuffer,
        name: &str,
        body: impl FnOnce(vk::CommandBuffer) -> R,
    ) -> R {
        self.begin(cmd, name);
        let r = body(cmd);
        self.end(cmd);
        r
    }

    /// Milliseconds per pass of the last recording, in recording order. Call after the submission
    /// has completed; waits for the query results if they are not yet available.
    pub fn results(&self) -> Result<Vec<PassTime>> {
        self.read(vk::QueryResultFlags::WAIT)
    }

    /// Like [`Profiler::results`], for a submission whose fence has signalled: no query wait.
    pub(crate) fn results_ready(&self) -> Result<Vec<PassTime>> {
        self.read(vk::QueryResultFlags::empty())
    }

    fn read(&self, wait: vk::QueryResultFlags) -> Result<Vec<PassTime>> {
        let n = self.names.len();
        if n == 0 {
            return Ok(Vec::new());
        }
        let mut stamps = vec![0u64; n * 2];
        unsafe {
            self.ctx.device.get_query_pool_results(
                self.pool,
                0,
                &mut stamps,
                vk::QueryResultFlags::TYPE_64 | wait,
            )
        }
        .vk("reading timestamps")?;
        let period = self.ctx.info.timestamp_period_ns as f64;
        Ok(self
            .names
            .iter()
            .enumerate()
            .map(|(i, name)| PassTime {
                name: name.clone(),
                ms: stamps[2 * i + 1].saturating_sub(stamps[2 * i]) as f64 * period * 1e-6,
            })
            .collect())
    }
}

impl Drop for Profiler {
    fn drop(&mut self) {
        // Deferred while a submission that may write its queries is in flight.
        let pool = self.pool;
        self.ctx.retire(Box::new(move |ctx| unsafe {
            ctx.device.destroy_query_pool(pool, None)
        }));
    }
}

/// Sums the times of passes whose name is `name` (a pass recorded several times).
pub fn total_ms(times: &[PassTime], name: &str) -> f64 {
    times.iter().filter(|t| t.name == name).map(|t| t.ms).sum()
}
