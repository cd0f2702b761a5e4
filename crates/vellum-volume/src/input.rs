//! What the command line calls an input: a file path, a DICOM folder, or a phantom spec such as
//! `phantom:shepp-logan:128`.

use crate::geometry::{Geometry, IDENTITY};
use crate::io::{self, RawSpec};
use crate::{phantom, Volume};
use std::path::Path;
use vellum_error::Result;

/// Loads `spec`: a phantom when it starts with `phantom:`, else a file or folder (raw when `raw`
/// is given).
pub fn load(spec: &str, raw: Option<&RawSpec>) -> Result<Volume> {
    open(spec, raw, None)
}

/// The one opener of a whole input, which the command line, scene files and Python share:
/// [`load`], then, for a headerless input given a position, voxel (0, 0, 0) placed at `origin`
/// (LPS millimetres) with the axes along L, P and S.
pub fn open(spec: &str, raw: Option<&RawSpec>, origin: Option<[f64; 3]>) -> Result<Volume> {
    let v = match phantom::parse_spec(spec) {
        Some(v) => v?,
        None => io::load(Path::new(spec), raw)?,
    };
    match origin {
        Some(o) => v.with_geometry(Geometry::lps(o, IDENTITY)?),
        None => Ok(v),
    }
}
