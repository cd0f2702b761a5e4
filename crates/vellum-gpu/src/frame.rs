//! Frames in flight. A [`Frames`] ring owns N slots (2–3 for interactive work, 1 for one-shot
//! tools); each slot has its own command pool and buffer, fence, timestamp profiler, staging ring
//! and keep-alive list. Recording a frame:
//!
//! 1. waits for the slot's previous submission (N frames ago) to complete, which on a steady ring
//!    has long happened, so the CPU runs up to N frames ahead of the GPU;
//! 2. reads that submission's timestamps without a blocking query wait (its fence has signalled),
//!    and frees what it kept alive;
//! 3. resets the pool, the queries and the staging ring, and hands a [`Frame`] to the caller;
//! 4. submits with the slot's fence and a serial number (see `gpu/lifetime.rs`).
//!
//! ## Staging
//! Per-frame data (uniforms, proxy vertices, transfer-function texels) goes into the slot's
//! [`StagingRing`]: one host-visible buffer, bump-allocated and reset when the slot is reused. A
//! frame that needs more grows it once (the old buffer is kept until the frame completes), so
//! steady-state frames allocate nothing.

use crate::context::Context;
use crate::profiler::{PassTime, Profiler};
use crate::resources::{Buffer, BufferDesc, BufferLocation, BufferSlice};
use crate::VkContext;
use ash::vk;
use std::any::Any;
use std::collections::VecDeque;
use std::sync::Arc;
use vellum_error::Result;

/// How to build a [`Frames`] ring.
#[derive(Clone, Debug)]
pub struct FramesDesc {
    /// Slots, so frames that may be in flight at once (at least 1).
    pub frames_in_flight: usize,
    /// Timed passes per frame.
    pub(crate) timestamp_capacity: u32,
    /// Initial bytes of each slot's staging ring (0 for none until first use).
    pub staging_bytes: u64,
    /// Names the command buffers in captures and messages.
    pub name: String,
}

impl FramesDesc {
    /// Frames for interactive or repeated rendering: 2 in flight, 32 timed passes, 1 MiB staging.
    pub fn interactive(name: &str) -> Self {
        FramesDesc {
            frames_in_flight: 2,
            timestamp_capacity: 32,
            staging_bytes: 1 << 20,
            name: name.to_string(),
        }
    }

    /// One slot for a tool that records, submits and waits.
    pub fn one_shot(name: &str, timestamp_capacity: u32) -> Self {
        FramesDesc {
            frames_in_flight: 1,
            timestamp_capacity,
            staging_bytes: 0,
            name: name.to_string(),
        }
    }
}

/// Bump allocator over a host-visible buffer usable as copy source, uniform, storage and vertex
/// buffer. Reset each time its slot is reused.
pub struct StagingRing {
    ctx: Arc<Context>,
    name: String,
    buffer: Option<Buffer>,
    head: u64,
    /// Buffers outgrown during the current frame, kept until it completes.
    retired: Vec<Buffer>,
}

/// Usage of a staging ring's buffer.
const RING_USAGE: vk::BufferUsageFlags = vk::BufferUsageFlags::from_raw(
    vk::BufferUsageFlags::TRANSFER_SRC.as_raw()
        | vk::BufferUsageFlags::UNIFORM_BUFFER.as_raw()
        | vk::BufferUsageFlags::STORAGE_BUFFER.as_raw()
        | vk::BufferUsageFlags::VERTEX_BUFFER.as_raw(),
);

impl StagingRing {
    fn new(ctx: &Arc<Context>, name: &str, bytes: u64) -> Result<Self> {
        let mut ring = StagingRing {
            ctx: ctx.clone(),
            name: name.to_string(),
            buffer: None,
            head: 0,
            retired: Vec::new(),
        };
        if bytes > 0 {
            ring.buffer = Some(ring.make(bytes)?);
        }
        Ok(ring)
    }

    fn make(&self, bytes: u64) -> Result<Buffer> {
        Buffer::new(
            &self.ctx,
            &self.name,
            &BufferDesc {
                size: bytes,
                usage: RING_USAGE,
                location: BufferLocation::Upload,
            },
        )
    }

    fn reset(&mut self) {
        self.head = 0;
        self.retired.clear();
    }

    /// Copies `bytes` into the ring at an offset aligned to `align` (a power of two; uniform
    /// offsets need the device's minimum) and returns where they are.
    pub fn push(&mut self, bytes: &[u8], align: u64) -> Result<BufferSlice> {
        self.push_parts(&[bytes], align)
    }

    /// [`StagingRing::push`] of `parts` one after the other, as one slice (a header and a table
    /// kept apart on the host, without joining them first).
    pub fn push_parts(&mut self, parts: &[&[u8]], align: u64) -> Result<BufferSlice> {
        let bytes_len: usize = parts.iter().map(|p| p.len()).sum();
        self.push_with(bytes_len, align, |dst| {
            let mut at = 0;
            for p in parts {
                dst[at..at + p.len()].copy_from_slice(p);
                at += p.len();
            }
        })
    }

    /// Reserves `len` bytes at an offset aligned to `align` and lets `fill` write them in place
    /// (a table made for this frame only, without a host buffer of its own).
    pub fn push_with(
        &mut self,
        len: usize,
        align: u64,
        fill: impl FnOnce(&mut [u8]),
    ) -> Result<BufferSlice> {
        let align = align.max(16);
        let size = len.max(4) as u64;
        let start = self.head.next_multiple_of(align);
        let capacity = self.buffer.as_ref().map_or(0, |b| b.size);
        if start + size > capacity {
            // Grow to fit this frame's data so far and this push; the old buffer may already be
            // referenced by this frame's commands, so it stays alive until the frame completes.
            let needed = (start + size)
                .max(2 * capacity)
                .next_power_of_two()
                .max(1 << 16);
            let fresh = self.make(needed)?;
            if let Some(old) = self.buffer.replace(fresh) {
                self.retired.push(old);
            }
            self.head = 0;
            return self.push_with(len, align, fill);
        }
        let buffer = self.buffer.as_mut().expect("grown above");
        let dst = buffer
            .mapped_mut()
            .ok_or_else(|| vellum_error::Error::Pipeline {
                name: "staging ring".into(),
                msg: "buffer is not host-visible".into(),
            })?;
        fill(&mut dst[start as usize..start as usize + len]);
        self.head = start + size;
        Ok(BufferSlice {
            raw: buffer.raw,
            offset: start,
            size,
        })
    }

    /// Copies a plain-data value (uniforms) into the ring.
    pub fn push_pod<T: bytemuck::Pod>(&mut self, value: &T) -> Result<BufferSlice> {
        let align = self
            .ctx
            .info
            .min_uniform_buffer_offset_alignment
            .max(1)
            .next_power_of_two();
        self.push(bytemuck::bytes_of(value), align)
    }

    /// Bytes in use this frame.
    pub fn used(&self) -> u64 {
        self.head
    }
}

/// Timings of a completed frame.
#[derive(Clone, Debug)]
pub struct FrameResult {
    /// The frame's number in this ring, from 0.
    pub index: u64,
    /// GPU milliseconds of each pass, in recording order.
    pub passes: Vec<PassTime>,
}

struct Slot {
    pool: vk::CommandPool,
    cmd: vk::CommandBuffer,
    fence: vk::Fence,
    profiler: Profiler,
    staging: StagingRing,
    keep: Vec<Box<dyn Any>>,
    /// (frame index, submission serial) of the work in flight on this slot.
    in_flight: Option<(u64, u64)>,
}

/// The frame being recorded: its command buffer, profiler and staging ring.
pub struct Frame<'a> {
    /// The command buffer being recorded.
    pub cmd: vk::CommandBuffer,
    /// The frame's timestamp profiler: passes open and close their names on it.
    pub profiler: &'a mut Profiler,
    /// The frame's staging ring: bump-allocated host memory for uniforms, vertices and texels.
    pub staging: &'a mut StagingRing,
    keep: &'a mut Vec<Box<dyn Any>>,
    /// The frame's number in its ring, from 0.
    pub index: u64,
    /// The ring slot it records into (`index % len`): per-slot objects such as a swapchain's
    /// acquire semaphores are indexed by it.
    pub slot: usize,
}

/// Semaphores a frame's submission waits on and signals (a swapchain's acquire and present).
#[derive(Clone, Debug, Default)]
pub struct SubmitSync {
    /// Semaphores to wait for, each before the given stages.
    pub wait: Vec<(vk::Semaphore, vk::PipelineStageFlags2)>,
    /// Semaphores signalled once the frame's commands complete.
    pub signal: Vec<vk::Semaphore>,
}

impl Frame<'_> {
    /// Keeps `object` alive until this frame has completed on the GPU.
    pub fn keep_alive<T: Any>(&mut self, object: T) {
        self.keep.push(Box::new(object));
    }
}

/// Host time of the last [`Frames::frame`] call, in ms.
#[derive(Copy, Clone, Debug, Default, serde::Serialize)]
pub struct HostTimes {
    /// Blocked on the fence of the slot's previous frame (the GPU is behind).
    pub(crate) wait_ms: f64,
    /// Recording the commands and submitting them.
    pub record_submit_ms: f64,
}

/// A ring of frames in flight.
pub struct Frames {
    ctx: Arc<Context>,
    slots: Vec<Slot>,
    next: usize,
    frame_index: u64,
    finished: VecDeque<FrameResult>,
    name: String,
    last_host: HostTimes,
}

impl Frames {
    /// Creates the slots.
    pub fn new(ctx: &Arc<Context>, desc: &FramesDesc) -> Result<Self> {
        let mut frames = Frames {
            ctx: ctx.clone(),
            slots: Vec::new(),
            next: 0,
            frame_index: 0,
            finished: VecDeque::new(),
            name: desc.name.clone(),
            last_host: HostTimes::default(),
        };
        for i in 0..desc.frames_in_flight.max(1) {
            let pool_info = vk::CommandPoolCreateInfo::default()
                .queue_family_index(ctx.queue_family)
                .flags(vk::CommandPoolCreateFlags::TRANSIENT);
            let pool = unsafe { ctx.device.create_command_pool(&pool_info, None) }
                .vk(format!("creating a command pool for {}", desc.name))?;
            // Pushed at once so that Drop destroys it whatever fails next.
            frames.slots.push(Slot {
                pool,
                cmd: vk::CommandBuffer::null(),
                fence: vk::Fence::null(),
                profiler: Profiler::new(ctx, desc.timestamp_capacity.max(1))?,
                staging: StagingRing::new(
                    ctx,
                    &format!("{} staging {i}", desc.name),
                    desc.staging_bytes,
                )?,
                keep: Vec::new(),
                in_flight: None,
            });
            let slot = frames.slots.last_mut().expect("just pushed");
            let alloc = vk::CommandBufferAllocateInfo::default()
                .command_pool(pool)
                .level(vk::CommandBufferLevel::PRIMARY)
                .command_buffer_count(1);
            slot.cmd = unsafe { ctx.device.allocate_command_buffers(&alloc) }
                .vk(format!("allocating a command buffer for {}", desc.name))?[0];
            ctx.set_name(slot.cmd, &format!("{} {i}", desc.name));
            slot.fence = unsafe {
                ctx.device
                    .create_fence(&vk::FenceCreateInfo::default(), None)
            }
            .vk("creating a frame fence")?;
        }
        Ok(frames)
    }

    /// Frames that may be in flight at once.
    pub fn len(&self) -> usize {
        self.slots.len()
    }

    /// Always false: a ring has at least one slot.
    pub fn is_empty(&self) -> bool {
        self.slots.is_empty()
    }

    /// Waits for slot `i`'s submission, if any, then collects its timings and frees what it held.
    fn retire_slot(&mut self, i: usize, wait: bool) -> Result<bool> {
        let ctx = self.ctx.clone();
        let slot = &mut self.slots[i];
        let Some((index, serial)) = slot.in_flight else {
            return Ok(true);
        };
        if wait {
            unsafe { ctx.device.wait_for_fences(&[slot.fence], true, u64::MAX) }
                .vk(format!("waiting for frame {index} of {}", self.name))?;
        } else if !unsafe { ctx.device.get_fence_status(slot.fence) }
            .vk(format!("polling frame {index} of {}", self.name))?
        {
            return Ok(false);
        }
        unsafe { ctx.device.reset_fences(&[slot.fence]) }.vk("resetting a frame fence")?;
        slot.in_flight = None;
        // The fence has signalled, so the timestamps are available: no blocking query wait.
        let passes = slot.profiler.results_ready()?;
        slot.keep.clear();
        slot.staging.reset();
        ctx.mark_completed(serial);
        self.finished.push_back(FrameResult { index, passes });
        Ok(true)
    }

    /// Collects every frame that has completed, without waiting.
    pub fn poll(&mut self) -> Result<()> {
        for i in 0..self.slots.len() {
            self.retire_slot(i, false)?;
        }
        Ok(())
    }

    /// Waits for every frame in flight.
    pub fn wait_idle(&mut self) -> Result<()> {
        // Oldest first, so that results come out in order.
        for k in 0..self.slots.len() {
            let i = (self.next + k) % self.slots.len();
            self.retire_slot(i, true)?;
        }
        Ok(())
    }

    /// Waits for every frame in flight and returns the timings of the newest one (the one-shot
    /// tools' ending).
    pub fn finish(&mut self) -> Result<Vec<PassTime>> {
        self.wait_idle()?;
        Ok(self
            .take_finished()
            .pop()
            .map(|r| r.passes)
            .unwrap_or_default())
    }

    /// Whether completed frames wait in [`Frames::take_finished`] (after [`Frames::poll`]).
    pub fn has_finished(&self) -> bool {
        !self.finished.is_empty()
    }

    /// Timings of completed frames, oldest first; each frame's timings are returned once.
    pub fn take_finished(&mut self) -> Vec<FrameResult> {
        self.finished.drain(..).collect()
    }

    /// Records one frame with `record` and submits it. Blocks only while the slot it needs is
    /// still in flight. Returns what `record` returned and the frame's index.
    pub fn frame<R>(&mut self, record: impl FnOnce(&mut Frame) -> Result<R>) -> Result<(R, u64)> {
        self.frame_sync(|f| Ok((record(f)?, SubmitSync::default())))
    }

    /// Waits until the next frame's slot is free and returns its index: per-slot objects (an
    /// acquire semaphore) may then be reused before [`Frames::frame_sync`] records into it.
    pub fn next_slot(&mut self) -> Result<usize> {
        let i = self.next;
        self.retire_slot(i, true)?;
        Ok(i)
    }

    /// [`Frames::frame`] whose submission also waits on and signals the semaphores `record`
    /// returns (a window's frame: wait for the acquired image, signal for presentation).
    pub fn frame_sync<R>(
        &mut self,
        record: impl FnOnce(&mut Frame) -> Result<(R, SubmitSync)>,
    ) -> Result<(R, u64)> {
        let i = self.next;
        let started = std::time::Instant::now();
        self.retire_slot(i, true)?;
        let waited = started.elapsed();
        let ctx = self.ctx.clone();
        let index = self.frame_index;
        let slot = &mut self.slots[i];
        ctx.begin_recording(&format!("frame {index} of {}", self.name))?;
        let begun = unsafe {
            ctx.device
                .reset_command_pool(slot.pool, vk::CommandPoolResetFlags::empty())
        }
        .vk("resetting a frame's command pool")
        .and_then(|()| {
            let begin = vk::CommandBufferBeginInfo::default()
                .flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT);
            unsafe { ctx.device.begin_command_buffer(slot.cmd, &begin) }
                .vk(format!("beginning frame {index} of {}", self.name))
        });
        if let Err(e) = begun {
            ctx.end_recording();
            return Err(e);
        }
        let recorded = (|| {
            slot.profiler.reset(slot.cmd);
            let mut frame = Frame {
                cmd: slot.cmd,
                profiler: &mut slot.profiler,
                staging: &mut slot.staging,
                keep: &mut slot.keep,
                index,
                slot: i,
            };
            let (out, sync) = record(&mut frame)?;
            unsafe { ctx.device.end_command_buffer(slot.cmd) }
                .vk(format!("ending frame {index} of {}", self.name))?;
            let serial = ctx.next_serial();
            let cmd_infos = [vk::CommandBufferSubmitInfo::default().command_buffer(slot.cmd)];
            let waits: Vec<_> = sync
                .wait
                .iter()
                .map(|&(s, stage)| {
                    vk::SemaphoreSubmitInfo::default()
                        .semaphore(s)
                        .stage_mask(stage)
                })
                .collect();
            let signals: Vec<_> = sync
                .signal
                .iter()
                .map(|&s| {
                    vk::SemaphoreSubmitInfo::default()
                        .semaphore(s)
                        .stage_mask(vk::PipelineStageFlags2::ALL_COMMANDS)
                })
                .collect();
            let submit = [vk::SubmitInfo2::default()
                .command_buffer_infos(&cmd_infos)
                .wait_semaphore_infos(&waits)
                .signal_semaphore_infos(&signals)];
            {
                let queue = ctx.queue();
                if let Err(e) = unsafe { ctx.device.queue_submit2(*queue, &submit, slot.fence) }
                    .vk(format!("submitting frame {index} of {}", self.name))
                {
                    // The serial was taken but nothing carries it: count it done so that garbage
                    // tagged with it is not held forever.
                    ctx.mark_completed(serial);
                    return Err(e);
                }
            }
            slot.in_flight = Some((index, serial));
            Ok(out)
        })();
        ctx.end_recording();
        // The retired staging buffers of this frame stay with the slot until it completes.
        let retired = std::mem::take(&mut slot.staging.retired);
        slot.keep
            .extend(retired.into_iter().map(|b| Box::new(b) as Box<dyn Any>));
        let out = recorded?;
        self.next = (i + 1) % self.slots.len();
        self.frame_index += 1;
        self.last_host = HostTimes {
            wait_ms: waited.as_secs_f64() * 1e3,
            record_submit_ms: (started.elapsed() - waited).as_secs_f64() * 1e3,
        };
        Ok((out, index))
    }

    /// Host times of the last frame recorded.
    pub fn host_times(&self) -> HostTimes {
        self.last_host
    }
}

impl Drop for Frames {
    fn drop(&mut self) {
        if let Err(e) = self.wait_idle() {
            // The device is lost or out of memory; waiting for idle is all that is left to try.
            log::error!("{e}");
            let _ = unsafe { self.ctx.device.device_wait_idle() };
        }
        for slot in &mut self.slots {
            slot.keep.clear();
            unsafe {
                if slot.fence != vk::Fence::null() {
                    self.ctx.device.destroy_fence(slot.fence, None);
                }
                // Destroying the pool frees its command buffer.
                self.ctx.device.destroy_command_pool(slot.pool, None);
            }
        }
    }
}

/// Timed passes a one-shot frame has room for.
const ONE_SHOT_PASSES: u32 = 64;

/// Records `record` into a one-slot frame, submits it and waits (the one-shot path for tools).
/// `what` names the work in error messages.
pub fn submit_once<R>(
    ctx: &Arc<Context>,
    what: &str,
    record: impl FnOnce(&mut Frame) -> Result<R>,
) -> Result<R> {
    Ok(submit_timed(ctx, what, record)?.0)
}

/// [`submit_once`] that also returns the times of the passes `record` opened on the frame's
/// profiler, in recording order.
pub fn submit_timed<R>(
    ctx: &Arc<Context>,
    what: &str,
    record: impl FnOnce(&mut Frame) -> Result<R>,
) -> Result<(R, Vec<PassTime>)> {
    let mut frames = Frames::new(ctx, &FramesDesc::one_shot(what, ONE_SHOT_PASSES))?;
    let (out, _) = frames.frame(record)?;
    Ok((out, frames.finish()?))
}
