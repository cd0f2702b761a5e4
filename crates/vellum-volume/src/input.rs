//! What the command line calls an input: a file path, a DICOM folder, or a phantom spec such as
//! `phantom:shepp-logan:128`.

use crate::io::{self, RawSpec};
use crate::{phantom, Volume};
use std::path::Path;
use vellum_error::Result;

/// Loads `spec`: a phantom when it starts with `phantom:`, else a file or folder (raw when `raw`
/// is given).
pub fn load(spec: &str, raw: Option<&RawSpec>) -> Result<Volume> {
    match phantom::parse_spec(spec) {
        Some(v) => v,
        None => io::load(Path::new(spec), raw),
    }
}
