//! `vellum._vellum`, the compiled half of the Python package (issue 28): volumes as numpy arrays,
//! the importance map, ambient occlusion and its spectrum, and the device listing; rendering,
//! scenes and lines in `render.rs`, migration and feature maps in `features.rs`.
//!
//! ## Arrays
//! A C-contiguous numpy array indexed (z, y, x) has the library's voxel order (x fastest), so
//! voxels cross never reordered. An array is copied once into a `Volume`, which is frozen: its
//! voxels never change, so the GPU work reads them with the GIL released, and `.array` is a
//! read-only view of them with the volume as its base. Results come back as new arrays that own
//! their memory. Spacing, origin and direction keep the library's (x, y, z) order.
//!
//! ## Errors
//! Every library error becomes `vellum.Error` (a `ValueError`) carrying the library's sentence,
//! and so does every input this module refuses itself. A panic is a bug in vellum: it is caught
//! before it reaches Python and raised as a `RuntimeError` that says so.
//!
//! ## The device
//! One [`Context`] per process, made on first use (as the command line makes it: `VELLUM_DEVICE`,
//! `VELLUM_VALIDATION`) and kept until the process exits; a failed attempt is retried on the next
//! call. Its lock serialises the GPU work of all Python threads, since a context records one
//! submission at a time; the GIL is released meanwhile.

use numpy::prelude::*;
use numpy::{dtype, Element, PyArray1, PyArray3, PyArrayDescr, PyUntypedArray};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use vellum_error::one_line;
use vellum_gpu::{Context, ContextDesc};
use vellum_render::passes::importance::ImportanceMap;
use vellum_render::passes::occlusion::{parse_mapping, Method, Occlusion, OcclusionParams};
use vellum_volume::geometry::{Geometry, Space, IDENTITY};
use vellum_volume::{VoxelData, VoxelType};

mod features;
mod render;

pyo3::create_exception!(
    vellum,
    Error,
    PyValueError,
    "An input (a file, an array, a parameter) or the device is not what vellum expects; the message says what was expected, in one sentence."
);

/// Three numbers in (x, y, z) order, as Python sees a spacing or a row of the direction.
type Triple = (f64, f64, f64);

/// The library's error as `vellum.Error`, on one line.
pub(crate) fn to_py(e: vellum_error::Error) -> PyErr {
    Error::new_err(one_line(&e.to_string()))
}

/// A sentence of this module's own as `vellum.Error`.
pub(crate) fn refuse(sentence: String) -> PyErr {
    Error::new_err(sentence)
}

/// A caught panic as a `RuntimeError` that calls it what it is.
fn bug(panic: Box<dyn std::any::Any + Send>) -> PyErr {
    let what = panic
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| panic.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "no message".into());
    PyRuntimeError::new_err(format!(
        "vellum panicked ({}); this is a bug in vellum, please report it",
        one_line(&what)
    ))
}

/// Runs `work` with the GIL released: its error becomes `vellum.Error`, a panic a `RuntimeError`.
pub(crate) fn detached<T: Send>(
    py: Python<'_>,
    work: impl FnOnce() -> vellum_error::Result<T> + Send,
) -> PyResult<T> {
    match py.detach(|| catch_unwind(AssertUnwindSafe(work))) {
        Ok(result) => result.map_err(to_py),
        Err(panic) => Err(bug(panic)),
    }
}

/// The process's device, made on first use; its lock serialises the GPU work of all threads.
static DEVICE: Mutex<Option<Arc<Context>>> = Mutex::new(None);

/// Runs `work` on the process's device with the GIL released, holding the device's lock.
pub(crate) fn on_gpu<T: Send>(
    py: Python<'_>,
    work: impl FnOnce(&Arc<Context>) -> vellum_error::Result<T> + Send,
) -> PyResult<T> {
    detached(py, || {
        // After a panic the slot holds a whole context or none, so a poisoned lock is usable.
        let mut slot = DEVICE.lock().unwrap_or_else(|p| p.into_inner());
        let ctx = match slot.clone() {
            Some(ctx) => ctx,
            None => slot.insert(Context::new(&ContextDesc::default())?).clone(),
        };
        let out = work(&ctx);
        ctx.report_validation();
        out
    })
}

/// A count from Python (a radius, a number of bins) as the library's `u32`, or one sentence.
/// Zero passes, for the library to refuse with the sentence that names the limits.
fn count(name: &str, value: i64) -> PyResult<u32> {
    u32::try_from(value).map_err(|_| {
        refuse(format!(
            "{name} {value} is invalid; expected a positive whole number"
        ))
    })
}

/// `N` numbers from any iterable (a tuple, a list, a numpy array), or one sentence.
fn numbers<const N: usize>(name: &str, obj: &Bound<'_, PyAny>) -> PyResult<[f64; N]> {
    let bad = || {
        refuse(format!(
            "{name} is not {N} numbers; expected {N} numbers in (x, y, z) order"
        ))
    };
    let values = obj
        .try_iter()
        .map_err(|_| bad())?
        .map(|x| x?.extract::<f64>())
        .collect::<PyResult<Vec<f64>>>()
        .map_err(|_| bad())?;
    values.try_into().map_err(|_| bad())
}

/// A direction matrix from three rows of three numbers (nested sequences or a 3x3 array).
fn direction_matrix(obj: &Bound<'_, PyAny>) -> PyResult<[[f64; 3]; 3]> {
    let bad =
        || refuse("direction is not a 3x3 matrix; expected three rows of three numbers".into());
    let rows = obj
        .try_iter()
        .map_err(|_| bad())?
        .map(|row| numbers::<3>("a row of direction", &row?))
        .collect::<PyResult<Vec<[f64; 3]>>>()?;
    rows.try_into().map_err(|_| bad())
}

/// The voxel type an array of `descr` is kept as: its own where vellum has it, else the nearest
/// that holds it (bool → uint8, int8 → int16, other integers and floats → float32).
fn voxel_type_for(descr: &Bound<'_, PyArrayDescr>) -> PyResult<VoxelType> {
    match (descr.kind(), descr.itemsize()) {
        (b'b', _) | (b'u', 1) => Ok(VoxelType::U8),
        (b'u', 2) => Ok(VoxelType::U16),
        (b'i', 1 | 2) => Ok(VoxelType::I16),
        (b'u' | b'i' | b'f', _) => Ok(VoxelType::F32),
        _ => Err(refuse(format!(
            "an array of dtype {descr} cannot be a volume; expected uint8, uint16, int16 or float32 (other integer, float and bool arrays are converted)"
        ))),
    }
}

/// numpy's name of a voxel type.
fn numpy_name(t: VoxelType) -> &'static str {
    match t {
        VoxelType::U8 => "uint8",
        VoxelType::U16 => "uint16",
        VoxelType::I16 => "int16",
        VoxelType::F32 => "float32",
    }
}

/// The elements of a C-contiguous 3-D array of `T`, in memory order.
fn flat<T: Element>(array: &Bound<'_, PyAny>) -> PyResult<Vec<T>> {
    Ok(array.cast::<PyArray3<T>>()?.to_vec()?)
}

/// The voxels of a 3-D array-like indexed (z, y, x): dims (x, y, z) and the voxels, x fastest.
/// Any layout is made C-contiguous and native-endian, and dtypes as [`voxel_type_for`] says.
fn voxels_of(obj: &Bound<'_, PyAny>) -> PyResult<([usize; 3], VoxelData)> {
    let py = obj.py();
    let np = py.import("numpy")?;
    let array = np.call_method1("asarray", (obj,)).map_err(|e| {
        refuse(format!(
            "the input cannot be read as a numpy array ({}); expected a 3-D array indexed (z, y, x)",
            one_line(&e.to_string())
        ))
    })?;
    let untyped = array.cast::<PyUntypedArray>()?;
    if untyped.ndim() != 3 {
        return Err(refuse(format!(
            "a {}-D array cannot be a volume; expected a 3-D array indexed (z, y, x)",
            untyped.ndim()
        )));
    }
    let [nz, ny, nx] = [untyped.shape()[0], untyped.shape()[1], untyped.shape()[2]];
    // Empty and absurd grids are refused before anything is copied.
    vellum_volume::check_dims([nx, ny, nz]).map_err(to_py)?;
    let voxel_type = voxel_type_for(&untyped.dtype())?;
    let kwargs = PyDict::new(py);
    kwargs.set_item("dtype", numpy_name(voxel_type))?;
    let array = np.call_method("ascontiguousarray", (&array,), Some(&kwargs))?;
    let data = match voxel_type {
        VoxelType::U8 => VoxelData::U8(flat(&array)?),
        VoxelType::U16 => VoxelData::U16(flat(&array)?),
        VoxelType::I16 => VoxelData::I16(flat(&array)?),
        VoxelType::F32 => VoxelData::F32(flat(&array)?),
    };
    Ok(([nx, ny, nz], data))
}

/// Voxels of `dims` (x, y, z), x fastest, as a numpy array indexed (z, y, x). The vector becomes
/// the array's memory without another copy.
fn to_numpy(py: Python<'_>, dims: [usize; 3], data: VoxelData) -> PyResult<Bound<'_, PyAny>> {
    fn shaped<T: Element>(
        py: Python<'_>,
        [nx, ny, nz]: [usize; 3],
        v: Vec<T>,
    ) -> PyResult<Bound<'_, PyAny>> {
        Ok(PyArray1::from_vec(py, v).reshape([nz, ny, nx])?.into_any())
    }
    match data {
        VoxelData::U8(v) => shaped(py, dims, v),
        VoxelData::U16(v) => shaped(py, dims, v),
        VoxelData::I16(v) => shaped(py, dims, v),
        VoxelData::F32(v) => shaped(py, dims, v),
    }
}

/// `data` (x fastest, of a grid of `dims`) as a numpy array (z, y, x) over the same memory,
/// kept alive by `owner`, the frozen volume that holds it.
fn view_of<'py, T: Element>(
    owner: &Bound<'py, PyVolume>,
    [nx, ny, nz]: [usize; 3],
    data: &[T],
) -> PyResult<Bound<'py, PyAny>> {
    let view = numpy::ndarray::ArrayView3::from_shape((nz, ny, nx), data)
        .map_err(|e| refuse(format!("the volume's voxels do not fill its grid ({e})")))?;
    // SAFETY: the array borrows `data`, which lives in `owner`'s `inner`; `owner` is frozen (the
    // data never moves or changes) and becomes the array's base, so it outlives the array.
    let array = unsafe { PyArray3::borrow_from_array(&view, owner.clone().into_any()) };
    Ok(array.into_any())
}

/// A 3-D scalar volume: voxels, spacing, origin and direction.
///
/// Volume(array, spacing=(1, 1, 1), origin=(0, 0, 0), direction=None)
///
/// `array` is a 3-D array indexed (z, y, x). uint8, uint16, int16 and float32 are kept as they
/// are; bool becomes uint8, int8 int16, and other integer and float types float32 (integers
/// beyond 2**24 and float64 values round). Any layout is accepted (it is copied C-contiguous);
/// complex, string, object and date arrays, and NaN or infinite voxels, are refused. `spacing`
/// and `origin` are (x, y, z), as volume files give them; `direction` is a 3x3 rotation, row by
/// row, whose column c is the direction of index axis c (x first), by default the identity.
/// Origin and direction are kept as given, with no claim of an anatomical (LPS) orientation.
/// Bad input raises `vellum.Error` with one sentence.
#[pyclass(name = "Volume", module = "vellum", frozen)]
pub(crate) struct PyVolume {
    pub(crate) inner: vellum_volume::Volume,
}

#[pymethods]
impl PyVolume {
    #[new]
    #[pyo3(signature = (array, spacing = None, origin = None, direction = None))]
    fn new(
        array: &Bound<'_, PyAny>,
        spacing: Option<&Bound<'_, PyAny>>,
        origin: Option<&Bound<'_, PyAny>>,
        direction: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        let (dims, data) = voxels_of(array)?;
        let spacing = spacing.map_or(Ok([1.0; 3]), |s| numbers("spacing", s))?;
        let geometry = Geometry {
            origin: origin.map_or(Ok([0.0; 3]), |o| numbers("origin", o))?,
            direction: direction.map_or(Ok(IDENTITY), direction_matrix)?,
            space: Space::Unknown,
        };
        let inner = vellum_volume::Volume::new(dims, spacing, data)
            .and_then(|v| v.with_geometry(geometry))
            .map_err(to_py)?;
        inner.check_finite("the array").map_err(to_py)?;
        Ok(PyVolume { inner })
    }

    /// The voxels as a read-only numpy view indexed (z, y, x), of the volume's dtype: no copy,
    /// and the volume stays alive as long as the view does. `.array.copy()` to change them.
    #[getter]
    fn array<'py>(slf: &Bound<'py, Self>) -> PyResult<Bound<'py, PyAny>> {
        let v = &slf.get().inner;
        let view = match &v.data {
            VoxelData::U8(d) => view_of(slf, v.dims, d)?,
            VoxelData::U16(d) => view_of(slf, v.dims, d)?,
            VoxelData::I16(d) => view_of(slf, v.dims, d)?,
            VoxelData::F32(d) => view_of(slf, v.dims, d)?,
        };
        view.getattr("flags")?.setattr("writeable", false)?;
        Ok(view)
    }

    /// The size of a voxel along x, y and z.
    #[getter]
    fn spacing(&self) -> Triple {
        let [x, y, z] = self.inner.spacing;
        (x, y, z)
    }

    /// The position of voxel (0, 0, 0), as (x, y, z).
    #[getter]
    fn origin(&self) -> Triple {
        let [x, y, z] = self.inner.geometry.origin;
        (x, y, z)
    }

    /// The direction matrix, row by row; column c is the direction of index axis c (x first).
    #[getter]
    fn direction(&self) -> (Triple, Triple, Triple) {
        let [r0, r1, r2] = self.inner.geometry.direction.map(|[a, b, c]| (a, b, c));
        (r0, r1, r2)
    }

    /// The array's shape, (z, y, x).
    #[getter]
    fn shape(&self) -> (usize, usize, usize) {
        let [x, y, z] = self.inner.dims;
        (z, y, x)
    }

    /// The voxels' numpy dtype: uint8, uint16, int16 or float32.
    #[getter]
    fn dtype<'py>(&self, py: Python<'py>) -> Bound<'py, PyArrayDescr> {
        match self.inner.voxel_type() {
            VoxelType::U8 => dtype::<u8>(py),
            VoxelType::U16 => dtype::<u16>(py),
            VoxelType::I16 => dtype::<i16>(py),
            VoxelType::F32 => dtype::<f32>(py),
        }
    }

    fn __repr__(&self) -> String {
        let (z, y, x) = self.shape();
        let [sx, sy, sz] = self.inner.spacing;
        format!(
            "Volume(shape=({z}, {y}, {x}), dtype={}, spacing=({sx}, {sy}, {sz}))",
            numpy_name(self.inner.voxel_type())
        )
    }
}

/// Reads a volume as the command line does: NRRD (.nrrd, .nhdr), NIfTI (.nii, .nii.gz),
/// MetaImage (.mhd, .mha), a folder of one DICOM series, or an OME-Zarr store (its full
/// resolution, or the pyramid's `level`; `time` and `channel` pick one of a store's time points
/// and channels, as `--time` and `--channel` do). The GIL is released while it reads.
#[pyfunction]
#[pyo3(signature = (path, time = None, channel = None, level = None))]
fn read(
    py: Python<'_>,
    path: PathBuf,
    time: Option<usize>,
    channel: Option<usize>,
    level: Option<usize>,
) -> PyResult<PyVolume> {
    let pick = vellum_volume::io::ome_zarr::Pick { time, channel };
    let inner = detached(py, move || match level {
        Some(l) => vellum_volume::io::load_level(&path, pick, l),
        None => vellum_volume::io::load_picked(&path, None, pick),
    })?;
    Ok(PyVolume { inner })
}

/// How stores on a server (`http://` and `https://` URLs, read wherever a path is) are read
/// from now on, as the command line's `--cache-dir`, `--cache-mib` and `--http-timeout` say:
/// the chunk cache's folder (default `$XDG_CACHE_HOME/vellum/http`), its size in MiB (0 keeps
/// none; default 1024), and the seconds without a byte before a request is tried again (default
/// 20, with three more tries). Options not given keep their defaults.
#[pyfunction]
#[pyo3(signature = (cache_dir = None, cache_mib = None, timeout_s = None))]
fn remote(
    cache_dir: Option<PathBuf>,
    cache_mib: Option<u64>,
    timeout_s: Option<f64>,
) -> PyResult<()> {
    use vellum_volume::io::http_store::{configure, RemoteOptions};
    let mut o = RemoteOptions::default();
    if let Some(dir) = cache_dir {
        o.cache_dir = Some(dir);
    }
    if let Some(mib) = cache_mib {
        o.cache_mib = mib;
    }
    if let Some(s) = timeout_s {
        if !(s > 0.0 && s.is_finite()) {
            return Err(Error::new_err(format!(
                "timeout_s={s} is not a number of seconds; expected one above 0, such as 20"
            )));
        }
        o.timeout = std::time::Duration::from_secs_f64(s);
    }
    configure(o);
    Ok(())
}

/// The Vulkan devices, one dict each: `index`, `name`, `type`, `api_version`, `driver`,
/// `rejected` (why vellum cannot use the device, or None) and `chosen` (whether GPU work runs
/// on it: `VELLUM_DEVICE`, an index or part of a name, else the best usable device).
#[pyfunction]
fn devices(py: Python<'_>) -> PyResult<Vec<Bound<'_, PyDict>>> {
    let desc = ContextDesc {
        validation: Some(false),
        device: None,
    };
    let (candidates, chosen) = detached(py, move || vellum_gpu::context::probe_devices(&desc))?;
    candidates
        .into_iter()
        .map(|c| {
            let d = PyDict::new(py);
            d.set_item("index", c.index)?;
            d.set_item("name", c.name)?;
            d.set_item("type", c.device_type)?;
            d.set_item("api_version", c.api_version)?;
            d.set_item("driver", c.driver)?;
            d.set_item("rejected", c.rejected)?;
            d.set_item("chosen", Some(c.index) == chosen)?;
            Ok(d)
        })
        .collect()
}

/// The importance map ΔD = G∗V − V (paper eq. 1) of `volume` on the GPU, as a float32 array
/// indexed (z, y, x) in the volume's data units. G is a Gaussian of `radius` voxels (1 to 32):
/// σ = R/3 with taps −R..R and clamped borders, i.e.
/// `scipy.ndimage.gaussian_filter(v, R / 3, truncate=3, mode="nearest") - v`.
#[pyfunction]
fn importance<'py>(
    py: Python<'py>,
    volume: &Bound<'py, PyVolume>,
    radius: i64,
) -> PyResult<Bound<'py, PyAny>> {
    let radius = count("radius", radius)?;
    let v = &volume.get().inner;
    let delta_d = on_gpu(py, move |ctx| {
        Ok(ImportanceMap::new(ctx)?.compute(v, radius, false)?.delta_d)
    })?;
    to_numpy(py, delta_d.dims, delta_d.data)
}

// `mapping` and `method` arrive as `String`: borrowing a `&str` from Python needs the limited API
// of Python 3.10, and the wheel serves 3.9.

/// What `occlusion` and `spectrum` compute: full resolution, `mapping` and `method` as the
/// command line's `--mapping` and `--method` take them, and `bins` × `bins` spectrum bins.
fn occlusion_params(
    radius: i64,
    mapping: &str,
    method: &str,
    bins: Option<i64>,
) -> PyResult<OcclusionParams> {
    let (visibility, neighbourhood) = parse_mapping(mapping).map_err(to_py)?;
    let bins = bins.map(|b| count("bins", b)).transpose()?;
    Ok(OcclusionParams {
        radius: count("radius", radius)?,
        visibility,
        neighbourhood,
        stride: 1,
        spectrum_bins: bins.map(|b| [b, b]),
        method: Method::parse(method).map_err(to_py)?,
        pad: None,
    })
}

/// Ambient occlusion of `volume` on the GPU (or the CPU FFT, when `method` picks it): for each
/// voxel, the mean visibility M over its neighbourhood of `radius` voxels, in [0, 1], as a
/// float32 array indexed (z, y, x). Intensities are normalised over the volume's range first.
/// `mapping`: "ramp" (M = intensity, ball), "gaussian" (M = intensity, Gaussian weights with
/// σ = R/3), "truncated:T0,T1" (a ramp from T0 to T1, fractions of the range) or
/// "tf:FILE.json" (a transfer function's opacity). `method`: "auto", "runs", "fft-gpu" or
/// "fft-cpu"; all give the same values. `range`: the data values that normalise to 0 and 1,
/// when `volume` is one block of a larger grid (the grid's min and max; `vellum.dask` passes
/// them); by default the volume's own.
#[pyfunction]
#[pyo3(signature = (volume, radius, mapping = String::from("ramp"), method = String::from("auto"), range = None))]
fn occlusion<'py>(
    py: Python<'py>,
    volume: &Bound<'py, PyVolume>,
    radius: i64,
    mapping: String,
    method: String,
    range: Option<(f64, f64)>,
) -> PyResult<Bound<'py, PyAny>> {
    let params = occlusion_params(radius, &mapping, &method, None)?;
    if let Some((lo, hi)) = range {
        if !(lo.is_finite() && hi.is_finite() && lo <= hi) {
            return Err(refuse(format!(
                "range ({lo}, {hi}) is invalid; expected finite (min, max) with min <= max"
            )));
        }
    }
    let v = &volume.get().inner;
    let o = on_gpu(py, move |ctx| {
        let range = range.map(|(lo, hi)| [lo, hi]);
        let (input, _) =
            vellum_render::passes::occlusion::OcclusionInput::upload_in_range(ctx, v, range)?;
        Ok(Occlusion::new(ctx)?.compute_on(&input, &params)?.occlusion)
    })?;
    to_numpy(py, o.dims, o.data)
}

/// The occlusion spectrum of `volume`: the 2-D histogram of (intensity, occlusion) over its
/// voxels, `bins` (1 to 4096) along each, as a uint32 array indexed (occlusion bin, intensity
/// bin). Intensity bins span the volume's min..max, occlusion bins 0..1. `radius`, `mapping`
/// and `method` are those of `occlusion`.
#[pyfunction]
#[pyo3(signature = (volume, radius, bins = 64, mapping = String::from("ramp"), method = String::from("auto")))]
fn spectrum<'py>(
    py: Python<'py>,
    volume: &Bound<'py, PyVolume>,
    radius: i64,
    bins: i64,
    mapping: String,
    method: String,
) -> PyResult<Bound<'py, PyAny>> {
    let params = occlusion_params(radius, &mapping, &method, Some(bins))?;
    let v = &volume.get().inner;
    let s = on_gpu(py, move |ctx| {
        Occlusion::new(ctx)?
            .compute(v, &params)?
            .spectrum
            .ok_or_else(|| {
                vellum_error::Error::Invalid(
                "the occlusion pass returned no spectrum though bins were given (a bug in vellum)"
                    .into(),
            )
            })
    })?;
    let [bins_intensity, bins_occlusion] = s.bins.map(|b| b as usize);
    Ok(PyArray1::from_vec(py, s.counts)
        .reshape([bins_occlusion, bins_intensity])?
        .into_any())
}

/// vellum's compiled core; import `vellum`, which re-exports it.
/// The validation layer's errors and warnings on the process's device so far, as
/// `(errors, warnings)`; `(0, 0)` before the device is made or with validation off
/// (`VELLUM_VALIDATION=1` turns it on). The tests assert that they stay at zero.
#[pyfunction]
fn validation_messages() -> (usize, usize) {
    let slot = DEVICE.lock().unwrap_or_else(|p| p.into_inner());
    slot.as_ref().map_or((0, 0), |ctx| {
        let m = ctx.messages();
        (m.errors, m.warnings)
    })
}

#[pymodule]
fn _vellum(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("Error", m.py().get_type::<Error>())?;
    m.add_class::<PyVolume>()?;
    m.add_function(wrap_pyfunction!(read, m)?)?;
    m.add_function(wrap_pyfunction!(remote, m)?)?;
    m.add_function(wrap_pyfunction!(devices, m)?)?;
    m.add_function(wrap_pyfunction!(importance, m)?)?;
    m.add_function(wrap_pyfunction!(occlusion, m)?)?;
    m.add_function(wrap_pyfunction!(spectrum, m)?)?;
    m.add_function(wrap_pyfunction!(validation_messages, m)?)?;
    render::add(m)?;
    features::add(m)?;
    Ok(())
}
