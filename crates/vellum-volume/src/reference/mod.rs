//! CPU reference algorithms: plain, obviously correct implementations that every GPU pass is
//! checked against in tests.
pub mod gaussian;
pub mod occlusion;
pub mod sobel;
