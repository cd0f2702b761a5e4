//! What the command line calls an input: a file path, a DICOM folder, or a phantom spec such as
//! `phantom:shepp-logan:128`.

use crate::geometry::{Geometry, IDENTITY};
use crate::io::ome_zarr::Pick;
use crate::io::{self, RawSpec};
use crate::{phantom, Volume};
use std::path::Path;
use vellum_error::Result;

/// Loads `spec`: a phantom when it starts with `phantom:`, else a file or folder (raw when `raw`
/// is given).
pub fn load(spec: &str, raw: Option<&RawSpec>) -> Result<Volume> {
    open(spec, raw, None, Pick::default())
}

/// The one opener of a whole input, which the command line, scene files and Python share:
/// [`load`] (a store's time point and channel as `pick` says), then, for a headerless input
/// given a position, voxel (0, 0, 0) placed at `origin` (LPS millimetres) with the axes along L,
/// P and S.
pub fn open(
    spec: &str,
    raw: Option<&RawSpec>,
    origin: Option<[f64; 3]>,
    pick: Pick,
) -> Result<Volume> {
    let v = match phantom::parse_spec(spec) {
        Some(_) if pick != Pick::default() => {
            return Err(vellum_error::Error::Invalid(format!(
                "`time` and `channels` pick a time point and a channel of an OME-Zarr store; {spec} is a phantom"
            )))
        }
        Some(v) => v?,
        None => io::load_picked(Path::new(spec), raw, pick)?,
    };
    match origin {
        Some(o) => v.with_geometry(Geometry::lps(o, IDENTITY)?),
        None => Ok(v),
    }
}
