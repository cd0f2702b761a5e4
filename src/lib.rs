//! vellum: illustrative volume rendering on Vulkan.
//!
//! The library's front door. The layers are crates under `crates/` (ARCHITECTURE.md draws the
//! graph; `tests/layering.rs` checks it), re-exported here under the names they always had:
//! [`gpu`] knows Vulkan and nothing about volumes (`vellum-gpu`); [`volume`] knows volumes and
//! nothing about Vulkan (`vellum-volume`, with [`input`], [`output`], [`team`] and [`memory`]);
//! [`classify`], [`passes`], [`imaging`] and [`render`] are `vellum-render`; the window is
//! `vellum-viewer`, behind the default feature `viewer`. The binary's tools (benchmarks, figures,
//! fuzzing, the showcase, MPI) are `vellum-tools`, which this library does not re-export.
//!
//! # Example
//!
//! Open a volume, render it in one of the two-level paper's styles, save a PNG (README.md shows
//! the same file, examples/render_png.rs; `cargo test` runs it here):
//!
#![doc = "```"]
#![doc = include_str!("../examples/render_png.rs")]
#![doc = "```"]

pub use vellum_error as error;
pub use vellum_error::{Error, Result};
pub use vellum_gpu as gpu;
pub use vellum_render::{classify, imaging, passes, plot, progress, render};
#[cfg(feature = "viewer")]
pub use vellum_viewer as viewer;
pub use vellum_volume as volume;
pub use vellum_volume::{input, memory, output, team};
