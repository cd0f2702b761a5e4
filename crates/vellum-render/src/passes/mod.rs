//! Passes join volumes and the GPU: each module records the dispatches of one technique and has a
//! CPU twin in `volume::reference` that tests compare it with.

pub mod chunked;
pub mod gpu_volume;
pub mod importance;
pub mod lines;
pub mod normals;
pub mod occlusion;
pub mod occlusion_analysis;
pub mod occlusion_fft;
pub mod paging;
pub mod volume_image;
