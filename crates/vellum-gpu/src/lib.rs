#![warn(missing_docs)]
//! The Vulkan layer: context, memory, commands, barriers, pipelines and timing. It knows nothing
//! about volumes or rendering techniques; `vellum-render`'s passes and renderers build on it.
//! Beneath it is only `vellum-error`.

/// The workspace's glsl/ folder, whose files build.rs compiled into `shaders`.
pub const GLSL_DIR: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../glsl");

pub(crate) mod barrier;
pub mod commands;
pub mod context;
pub(crate) mod frame;
pub mod graphics;
pub mod interface;
pub(crate) mod lifetime;
pub mod pipeline;
pub(crate) mod pipeline_cache;
pub mod profiler;
pub mod resources;
pub(crate) mod shaders;
pub mod swapchain;
pub mod transfer;
pub mod validation;
mod vk_context;

/// The two Vulkan names the crates above still say: the texel format of an image they create
/// (a pass decides what its images hold) and the command buffer a pass records into (a handle
/// it passes on to this crate's recording functions, never calls Vulkan with). Everything
/// else of Vulkan stays in this crate.
pub use ash::vk::{CommandBuffer, Format};
pub use barrier::Access;
pub use context::{Context, ContextDesc, DeviceCandidate, DeviceInfo, Presentation};
pub use frame::{submit_once, submit_timed};
pub use frame::{Frame, FrameResult, Frames, FramesDesc, HostTimes, StagingRing, SubmitSync};
pub use lifetime::TransferCount;
pub use pipeline::{Bind, BindingKind, ComputePipeline};
pub use pipeline_cache::{PipelineCache, PipelineDesc};
pub use profiler::{PassTime, Profiler};
pub use resources::{Buffer, BufferDesc, BufferSlice, Image, ImageDesc, Sampler};
pub(crate) use vk_context::VkContext;
