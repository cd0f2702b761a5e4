//! What an OME-Zarr store declares, checked before anything is allocated or read (issue 40):
//! shapes, chunk grids and level counts within sane limits, scales and translations that are
//! positive and finite numbers a renderer can work with, the multiscale's own transformations
//! applied, and levels that are what they say (each one the same physical extent as level 0, at
//! its own scale).
//!
//! Every refusal is one sentence naming the store, the level and the limit.

use super::guarded_store::{GuardedStore, MAX_CHUNK_BYTES};
use serde_json::Value;
use std::path::Path;
use vellum_error::{Error, Result};
use zarrs::array::Array;

/// One level of a multiscale image.
#[derive(Clone, Debug, PartialEq)]
pub struct Level {
    /// The array's path in the store ("0", "1", …).
    pub path: String,
    /// Voxels along x, y, z.
    pub dims: [usize; 3],
    /// Chunk edge along x, y, z.
    pub chunk: [usize; 3],
    /// Physical voxel size along x, y, z (the dataset's scale).
    pub spacing: [f64; 3],
    /// Physical position of voxel (0, 0, 0) along x, y, z (the dataset's translation).
    pub origin: [f64; 3],
}

/// Voxels along one axis of a level at most (2^20).
pub const MAX_AXIS: u64 = 1 << 20;
/// Voxels of one level at most (2^42: a 16384³ volume).
pub const MAX_LEVEL_VOXELS: u128 = 1 << 42;
/// Chunks in one level's grid at most (2^24): the writers and the chunked passes keep a word
/// per chunk.
pub const MAX_CHUNKS: u128 = 1 << 24;
/// Levels (datasets) of one multiscale at most.
pub const MAX_DATASETS: usize = 32;
/// Voxel sizes (scales) from 1e-12 to 1e12 units, at most 1e4 times longer on one axis than on
/// another: beyond those, a volume's box cannot be drawn (its thinnest axis rounds to nothing).
pub const SCALE_RANGE: [f64; 2] = [1e-12, 1e12];
pub const MAX_ANISOTROPY: f64 = 1e4;
/// Translations at most 1e15 units from the origin.
pub const MAX_TRANSLATION: f64 = 1e15;

fn invalid(path: &Path, what: impl std::fmt::Display) -> Error {
    Error::format(path, what.to_string())
}

/// The datasets list: at most [`MAX_DATASETS`], each path named once.
pub fn datasets(path: &Path, datasets: &[Value]) -> Result<()> {
    if datasets.len() > MAX_DATASETS {
        return Err(invalid(
            path,
            format!(
                "lists {} datasets; expected at most {MAX_DATASETS} levels",
                datasets.len()
            ),
        ));
    }
    let mut seen = std::collections::HashSet::new();
    for d in datasets {
        if let Some(p) = d["path"].as_str() {
            let p = p.trim_matches('/');
            if !seen.insert(p) {
                return Err(invalid(
                    path,
                    format!(
                        "lists level {p} twice among its datasets; expected one array per level"
                    ),
                ));
            }
        }
    }
    Ok(())
}

/// An array's declared shape and chunk grid, all axes (leading t and c included).
pub struct Limits {
    shape: Vec<u64>,
    chunk: Vec<u64>,
    chunk_bytes: u64,
}

impl Limits {
    /// The shape and chunk grid `array` declares, and the bytes one chunk decodes to.
    pub fn of_array(path: &Path, name: &str, array: &Array<GuardedStore>) -> Result<(Self, u64)> {
        let shape = array.shape().to_vec();
        let chunk: Vec<u64> = array
            .chunk_shape(&vec![0; shape.len()])
            .map_err(|e| {
                invalid(
                    path,
                    format!("level {name} has no regular chunk grid ({e})"),
                )
            })?
            .iter()
            .map(|c| c.get())
            .collect();
        let size = array.data_type().fixed_size().unwrap_or(8) as u128;
        let bytes = chunk.iter().map(|&c| c as u128).product::<u128>() * size;
        let chunk_bytes = u64::try_from(bytes).unwrap_or(u64::MAX);
        Ok((
            Limits {
                shape,
                chunk,
                chunk_bytes,
            },
            chunk_bytes,
        ))
    }

    /// Within the limits: no axis empty or longer than [`MAX_AXIS`], at most
    /// [`MAX_LEVEL_VOXELS`] voxels, chunks of at most [`MAX_CHUNK_BYTES`], at most
    /// [`MAX_CHUNKS`] of them.
    pub fn check(&self, path: &Path, name: &str, leading: usize) -> Result<()> {
        let spatial = &self.shape[leading.min(self.shape.len())..];
        if let Some(axis) = spatial.iter().position(|&n| n == 0) {
            return Err(invalid(
                path,
                format!(
                    "level {name} has shape {:?}, empty along {}; expected at least one voxel on every axis",
                    self.shape,
                    ["z", "y", "x"].get(axis).unwrap_or(&"an axis")
                ),
            ));
        }
        if let Some(&n) = spatial.iter().find(|&&n| n > MAX_AXIS) {
            return Err(invalid(
                path,
                format!("level {name} has shape {:?}, {n} voxels along an axis; expected at most {MAX_AXIS}", self.shape),
            ));
        }
        let voxels = spatial.iter().map(|&n| n as u128).product::<u128>();
        if voxels > MAX_LEVEL_VOXELS {
            return Err(invalid(
                path,
                format!("level {name} has shape {:?}, {voxels} voxels; expected at most {MAX_LEVEL_VOXELS}", self.shape),
            ));
        }
        if self.chunk_bytes > MAX_CHUNK_BYTES {
            return Err(invalid(
                path,
                format!(
                    "level {name} has chunks of {:?}, {} bytes each; expected at most {MAX_CHUNK_BYTES}",
                    self.chunk, self.chunk_bytes
                ),
            ));
        }
        let chunks = self
            .shape
            .iter()
            .zip(&self.chunk)
            .map(|(&n, &c)| n.div_ceil(c.max(1)) as u128)
            .product::<u128>();
        if chunks > MAX_CHUNKS {
            return Err(invalid(
                path,
                format!(
                    "level {name} has shape {:?} in chunks of {:?}, {chunks} chunks; expected at most {MAX_CHUNKS} (larger chunks)",
                    self.shape, self.chunk
                ),
            ));
        }
        Ok(())
    }
}

/// A scale (x, y, z): positive, within [`SCALE_RANGE`], and at most [`MAX_ANISOTROPY`] between
/// axes.
pub fn spacing(path: &Path, what: &str, s: [f64; 3]) -> Result<()> {
    let [lo, hi] = SCALE_RANGE;
    if s.iter().any(|&v| !(lo..=hi).contains(&v)) {
        return Err(invalid(
            path,
            format!("{what} is {s:?} (x, y, z); expected voxel sizes from {lo:e} to {hi:e}"),
        ));
    }
    let (min, max) = s
        .iter()
        .fold((f64::MAX, 0f64), |(a, b), &v| (a.min(v), b.max(v)));
    if max / min > MAX_ANISOTROPY {
        return Err(invalid(
            path,
            format!("{what} is {s:?} (x, y, z); expected at most {MAX_ANISOTROPY:e} times longer voxels on one axis than another"),
        ));
    }
    Ok(())
}

/// A translation (x, y, z): finite, within [`MAX_TRANSLATION`] of the origin.
pub fn origin(path: &Path, what: &str, t: [f64; 3]) -> Result<()> {
    if t.iter()
        .any(|v| !v.is_finite() || v.abs() > MAX_TRANSLATION)
    {
        return Err(invalid(
            path,
            format!("{what} is {t:?} (x, y, z); expected offsets within {MAX_TRANSLATION:e}"),
        ));
    }
    Ok(())
}

/// The multiscale's own `coordinateTransformations` (NGFF: applied after each dataset's): its
/// scale multiplies every level's voxel size and position, its translation moves them.
pub fn multiscale_transforms(
    path: &Path,
    ms: &Value,
    leading: usize,
    levels: &mut [Level],
) -> Result<()> {
    let Some(list) = ms.get("coordinateTransformations") else {
        return Ok(());
    };
    let list = list.as_array().ok_or_else(|| {
        invalid(
            path,
            "multiscales[0].coordinateTransformations is not a list; expected a list of scale and translation",
        )
    })?;
    for t in list {
        let kind = t["type"].as_str().unwrap_or("");
        if kind == "identity" {
            continue;
        }
        if kind != "scale" && kind != "translation" {
            return Err(invalid(
                path,
                format!("multiscales[0] has a {kind:?} coordinate transformation; expected scale, translation or identity"),
            ));
        }
        let v: Vec<f64> = t[kind]
            .as_array()
            .map(|a| a.iter().filter_map(Value::as_f64).collect())
            .unwrap_or_default();
        if v.len() != leading + 3 {
            return Err(invalid(
                path,
                format!(
                    "multiscales[0]'s {kind} is {}; expected {} numbers (the inline form; a path to a file is not read)",
                    t[kind],
                    leading + 3
                ),
            ));
        }
        let xyz = [v[leading + 2], v[leading + 1], v[leading]];
        for l in levels.iter_mut() {
            if kind == "scale" {
                l.spacing = std::array::from_fn(|a| l.spacing[a] * xyz[a]);
                l.origin = std::array::from_fn(|a| l.origin[a] * xyz[a]);
                spacing(
                    path,
                    &format!("level {}'s scale after the multiscale's", l.path),
                    l.spacing,
                )?;
            } else {
                l.origin = std::array::from_fn(|a| l.origin[a] + xyz[a]);
            }
            origin(
                path,
                &format!("level {}'s translation after the multiscale's", l.path),
                l.origin,
            )?;
        }
    }
    Ok(())
}

/// Each level covers level 0's extent at its own scale: its voxels times its scale differ from
/// level 0's by less than one of its voxels on every axis (levels halved by rounding up or down
/// both pass; an array at the wrong scale, or level 0 listed again, does not).
pub fn consistent_levels(path: &Path, levels: &[Level]) -> Result<()> {
    let Some(l0) = levels.first() else {
        return Ok(());
    };
    for l in &levels[1..] {
        for a in 0..3 {
            let extent = l.dims[a] as f64 * l.spacing[a];
            let want = l0.dims[a] as f64 * l0.spacing[a];
            if (extent - want).abs() >= l.spacing[a] * (1.0 + 1e-9) {
                let axis = ["x", "y", "z"][a];
                return Err(invalid(
                    path,
                    format!(
                        "level {} is {} voxels of {} along {axis}, {extent} in all, where level {} spans {want}; expected every level to cover the same extent",
                        l.path, l.dims[a], l.spacing[a], l0.path
                    ),
                ));
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn level(path: &str, n: usize, s: f64) -> Level {
        Level {
            path: path.into(),
            dims: [n; 3],
            chunk: [16; 3],
            spacing: [s; 3],
            origin: [0.0; 3],
        }
    }

    #[test]
    fn levels_must_cover_level_0s_extent() {
        let p = Path::new("s.ome.zarr");
        let ok = [level("0", 33, 1.0), level("1", 17, 2.0), level("2", 8, 4.0)];
        assert!(consistent_levels(p, &ok).is_ok());
        for bad in [
            [level("0", 32, 1.0), level("1", 40, 2.0)],
            [level("0", 32, 1.0), level("1", 22, 3.0)],
            [level("0", 32, 1.0), level("1", 32, 2.0)],
        ] {
            let e = consistent_levels(p, &bad).unwrap_err().to_string();
            assert!(e.contains("level 1") && e.contains("same extent"), "{e}");
        }
    }

    #[test]
    fn scales_must_be_positive_bounded_and_not_too_anisotropic() {
        let p = Path::new("s.ome.zarr");
        assert!(spacing(p, "scale", [0.5, 0.5, 2.0]).is_ok());
        for bad in [
            [-1.0, 1.0, 1.0],
            [0.0, 1.0, 1.0],
            [1e308, 1.0, 1.0],
            [1e-308, 1.0, 1.0],
            [1.0, 1.0, 1e5],
            [f64::NAN, 1.0, 1.0],
        ] {
            assert!(spacing(p, "scale", bad).is_err(), "{bad:?}");
        }
        assert!(origin(p, "t", [1e16, 0.0, 0.0]).is_err());
    }

    #[test]
    fn a_multiscale_transform_scales_and_moves_every_level() {
        let p = Path::new("s.ome.zarr");
        let mut levels = vec![level("0", 32, 1.0), level("1", 16, 2.0)];
        let ms = serde_json::json!({"coordinateTransformations": [
            {"type": "scale", "scale": [3.0, 2.0, 0.5]},
            {"type": "translation", "translation": [10.0, 0.0, 1.0]}
        ]});
        multiscale_transforms(p, &ms, 0, &mut levels).unwrap();
        assert_eq!(levels[1].spacing, [1.0, 4.0, 6.0]);
        assert_eq!(levels[0].origin, [1.0, 0.0, 10.0]);
        let bad = serde_json::json!({"coordinateTransformations": [{"type": "affine"}]});
        assert!(multiscale_transforms(p, &bad, 0, &mut levels).is_err());
    }
}
