//! Feature maps from Python: `vellum.migrate` moves a segmented feature into its own density
//! range (the feature-maps paper's migration, fuzzy boundary rebuilt) and returns the feature
//! volume with its `FeatureMap`, the JSON file `render(features=...)` classifies with.

use crate::{detached, refuse, to_py, PyVolume};
use pyo3::prelude::*;
use std::path::PathBuf;
use vellum_volume::feature::{self, Connectivity, Feature, FeatureMap, MigrateParams, Roi};

/// A feature as Python sees it: label, (lo, hi) private interval, (r, g, b) colour.
type FeatureRow = (String, (f64, f64), (f32, f32, f32));

/// A feature map: the features (label, private interval, colour) in their groups, over the
/// context's range, as `vellum migrate` writes it.
#[pyclass(name = "FeatureMap", module = "vellum")]
#[derive(Clone)]
pub struct PyFeatureMap {
    pub inner: FeatureMap,
}

#[pymethods]
impl PyFeatureMap {
    #[staticmethod]
    fn load(path: PathBuf) -> PyResult<Self> {
        Ok(PyFeatureMap {
            inner: FeatureMap::load(&path).map_err(to_py)?,
        })
    }

    #[staticmethod]
    fn from_json(text: &str) -> PyResult<Self> {
        Ok(PyFeatureMap {
            inner: FeatureMap::from_json_str(text).map_err(to_py)?,
        })
    }

    fn to_json(&self) -> String {
        self.inner.to_json()
    }

    /// Writes the map; `render(volume, features=PATH)` then classifies with it.
    fn save(&self, path: PathBuf) -> PyResult<()> {
        self.inner.save(&path).map_err(to_py)
    }

    /// Each feature as (label, (lo, hi) private interval, (r, g, b) colour).
    #[getter]
    fn features(&self) -> Vec<FeatureRow> {
        self.inner
            .features()
            .iter()
            .map(|(_, f)| {
                let [r, g, b] = f.color;
                (f.label.clone(), (f.interval[0], f.interval[1]), (r, g, b))
            })
            .collect()
    }
}

/// Migrates the feature of `volume` given by `mask` (a Volume of the same grid, non-zero
/// inside) or grown from `seeds` [(x, y, z), …] within `window=(lo, hi)` into a private density
/// interval above everything else, its fuzzy boundary rebuilt; returns the feature volume and
/// the feature map (appended to `features`, a FeatureMap, when given), as `vellum migrate`.
#[pyfunction]
#[pyo3(signature = (volume, label, seeds = None, window = None, mask = None, connectivity = 26, features = None))]
#[allow(clippy::too_many_arguments)]
pub fn migrate(
    py: Python<'_>,
    volume: &Bound<'_, PyVolume>,
    label: String,
    seeds: Option<Vec<(usize, usize, usize)>>,
    window: Option<(f64, f64)>,
    mask: Option<&Bound<'_, PyVolume>>,
    connectivity: u32,
    features: Option<&Bound<'_, PyFeatureMap>>,
) -> PyResult<(PyVolume, PyFeatureMap)> {
    let v = &volume.get().inner;
    let mask = mask.map(|m| &m.get().inner);
    let connectivity = Connectivity::parse(&connectivity.to_string()).map_err(to_py)?;
    let existing = features.map(|f| f.borrow().inner.clone());
    if existing
        .as_ref()
        .is_some_and(|m| m.feature(&label).is_some())
    {
        return Err(refuse(format!(
            "a feature labelled '{label}' exists already; expected a new label"
        )));
    }
    let (migrated, map) = detached(py, move || {
        let roi = match (mask, seeds, window) {
            (Some(m), _, _) => Roi::from_mask(m, v)?,
            (None, Some(s), Some((lo, hi))) => {
                let seeds: Vec<[usize; 3]> = s.iter().map(|&(x, y, z)| [x, y, z]).collect();
                Roi::grow(v, &seeds, [lo, hi], connectivity)?
            }
            _ => {
                return Err(vellum_error::Error::Invalid(
                    "no feature given; expected mask= or seeds= with window=(lo, hi)".into(),
                ))
            }
        };
        let params = MigrateParams {
            protected: existing
                .as_ref()
                .map(|m| m.features().iter().map(|(_, f)| f.interval).collect())
                .unwrap_or_default(),
            ..Default::default()
        };
        let m = feature::migrate(v, &roi, &params)?;
        let report = &m.report;
        let mut map = existing.unwrap_or_else(|| FeatureMap::new(report.in_range));
        let feature = Feature {
            label,
            description: String::new(),
            interval: report.interval,
            color: map.next_color(),
            source_range: Some(report.roi_range),
        };
        map.append(feature, None)?;
        Ok((m.volume, map))
    })?;
    Ok((PyVolume { inner: migrated }, PyFeatureMap { inner: map }))
}

/// Registers the class and `migrate` in the module.
pub fn add(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyFeatureMap>()?;
    m.add_function(wrap_pyfunction!(migrate, m)?)?;
    Ok(())
}
