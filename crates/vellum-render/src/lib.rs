#![warn(missing_docs)]
//! vellum's techniques and renderers, on top of `vellum-gpu` (Vulkan) and `vellum-volume`
//! (volumes without Vulkan).
//!
//! [`classify`] holds the transfer functions, occlusion and feature TFs, focus and modulation,
//! with their GPU textures, shared by every renderer; [`passes`] records one compute technique per
//! module into a caller's frame and never imports [`render`]; [`render`] assembles frames, draws
//! the levels (the slicer, the ray caster), runs the styles, holds the scene file and the session
//! every front end opens volumes through. [`imaging`] is 2D image processing on the CPU (the style
//! passes' references); [`progress`] and [`plot`] are small helpers of the passes' reports.

pub mod classify;
pub mod imaging;
pub mod passes;
pub mod plot;
pub mod progress;
pub mod render;
