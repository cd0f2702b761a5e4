//! vellum: illustrative volume rendering on Vulkan.
//!
//! Layers (see ARCHITECTURE.md): [`gpu`] knows Vulkan and nothing about volumes; [`volume`] knows
//! volumes and nothing about Vulkan; [`passes`] joins them, one module per technique.

pub mod bench;
pub mod classify;
pub mod error;
pub mod figures;
pub mod fuzz;
pub mod gpu;
pub mod imaging;
pub mod input;
pub mod output;
pub mod passes;
pub mod plot;
pub mod progress;
pub mod render;
pub mod viewer;
pub mod volume;

pub use error::{Error, Result};
