//! The frame: camera, transfer functions, proxy geometry, render passes.
//!
//! Everything here is plain CPU math and data; the GPU passes that consume it live beside it and
//! are the only modules of `render/` that touch Vulkan.

pub mod camera;
pub mod post;
pub mod proxy;
pub mod raycast;
pub mod scene;
pub mod slicer;
pub mod style;
pub mod targets;
