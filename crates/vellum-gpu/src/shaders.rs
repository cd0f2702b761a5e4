//! The SPIR-V of every shader under glsl/, compiled by build.rs and embedded in the library.

use vellum_error::{Error, Result};

include!(concat!(env!("OUT_DIR"), "/shaders.rs"));

/// The SPIR-V words of shader `name` (its path under glsl/, e.g. `importance/gauss1d.comp`).
pub(crate) fn spirv(name: &str) -> Result<Vec<u32>> {
    let bytes = SHADERS
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, b)| *b)
        .ok_or_else(|| Error::Pipeline {
            name: name.into(),
            msg: "no such shader was compiled".into(),
        })?;
    ash::util::read_spv(&mut std::io::Cursor::new(bytes)).map_err(|e| Error::Pipeline {
        name: name.into(),
        msg: format!("invalid SPIR-V: {e}"),
    })
}
