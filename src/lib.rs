//! vellum: illustrative volume rendering on Vulkan.
//!
//! Layers, bottom up (see ARCHITECTURE.md; `tests/layering.rs` checks them): [`gpu`] knows Vulkan
//! and nothing about volumes; [`volume`] knows volumes and nothing about Vulkan; [`classify`]
//! holds the transfer functions, occlusion and feature TFs, focus and modulation, with their GPU
//! textures, shared by every renderer; [`passes`] joins them, one module per compute technique,
//! recorded into a caller's frame, and never imports [`render`]; [`render`] assembles frames
//! (`render::frame`), draws the levels (the slicer, the ray caster), runs the styles and holds
//! the scene file; [`viewer`] is the window. [`imaging`] is 2D image processing on the CPU (the
//! style passes' references); [`bench`] and [`figures`] sit on top, beside the binary.

pub mod bench;
pub mod classify;
#[cfg(feature = "mpi")]
pub mod cluster;
pub mod error;
pub mod figures;
pub mod fuzz;
pub mod gpu;
pub mod imaging;
pub mod input;
pub mod memory;
pub mod output;
pub mod passes;
pub mod plot;
pub mod progress;
pub mod render;
pub mod showcase;
pub mod team;
#[cfg(feature = "viewer")]
pub mod viewer;
pub mod volume;

pub use error::{Error, Result};
