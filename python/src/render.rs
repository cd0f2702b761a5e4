//! Rendering from Python: `vellum.Scene` (the JSON scene file), `vellum.Renderer` (a scene's
//! volume, classification and renderer kept on the device for many frames) and `vellum.Image`
//! (a frame read back). A scene renders the pixels `vellum render --scene FILE` writes.

use crate::{on_gpu, refuse, to_py};
use numpy::prelude::*;
use numpy::PyArray1;
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict};
use std::path::PathBuf;
use std::sync::Mutex;
use vellum_render::render::overrides::{
    CameraAngles, Front, ModulationOverrides, SceneOverrides, StyleOverrides,
};
use vellum_render::render::scene::{NamedView, Scene};
use vellum_render::render::session::{Lod, Session, SessionOptions};
use vellum_render::render::style::LineSmooth;
use vellum_render::render::targets::{to_rgb8, FrameImage};
use vellum_render::render::view::View;

/// A scene: the input, classification, focus, camera, size, style and the rest, as the JSON
/// scene file holds them (`vellum render --save-scene`).
#[pyclass(name = "Scene", module = "vellum")]
#[derive(Clone)]
pub struct PyScene {
    pub inner: Scene,
}

#[pymethods]
impl PyScene {
    /// Reads a scene file; relative paths in it are resolved against its folder.
    #[staticmethod]
    fn load(path: PathBuf) -> PyResult<Self> {
        Ok(PyScene {
            inner: Scene::load(&path).map_err(to_py)?,
        })
    }

    /// A scene from the text of a scene file.
    #[staticmethod]
    fn from_json(text: &str) -> PyResult<Self> {
        Ok(PyScene {
            inner: Scene::from_json_str(text).map_err(to_py)?,
        })
    }

    /// The scene as the text of a scene file.
    fn to_json(&self) -> PyResult<String> {
        serde_json::to_string_pretty(&self.inner)
            .map_err(|e| refuse(format!("the scene could not be written as JSON ({e})")))
    }

    /// Writes the scene file (input paths made absolute).
    fn save(&self, path: PathBuf) -> PyResult<()> {
        self.inner.save(&path).map_err(to_py)
    }

    fn __repr__(&self) -> String {
        format!(
            "vellum.Scene(input={:?}, size={:?})",
            self.inner.input.path, self.inner.size
        )
    }
}

/// A rendered frame: `.rgba` (H, W, 4) uint8 over the scene's background, `.layers` (the
/// two-level layers as float arrays), `.timings` (GPU ms per pass); shown inline in Jupyter.
#[pyclass(name = "Image", module = "vellum", frozen)]
pub struct PyImage {
    frame: FrameImage,
    rgb: Vec<u8>,
    /// What streaming the frame through the brick cache did, when it did.
    stream: Option<vellum_render::render::bricked::StreamReport>,
    /// Where its shading's gradients came from (`Prepared::gradients`).
    gradients: &'static str,
}

fn rgba_of(rgb: &[u8]) -> Vec<u8> {
    rgb.chunks_exact(3)
        .flat_map(|p| [p[0], p[1], p[2], 255])
        .collect()
}

#[pymethods]
impl PyImage {
    /// The frame over the scene's background, (height, width, 4) uint8, alpha 255: the pixels
    /// `vellum render` writes to its PNG.
    #[getter]
    fn rgba<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let [w, h] = self.frame.size;
        let flat = PyArray1::from_vec(py, rgba_of(&self.rgb));
        Ok(flat.reshape([h as usize, w as usize, 4])?.into_any())
    }

    /// `composite` (premultiplied RGBA, float32 (H, W, 4)) and, for a two-level frame,
    /// `focus.phong`, `focus.diffuse`, `context` (the same) and `focus.depth` (float32 (H, W),
    /// +inf where no focus was hit).
    #[getter]
    fn layers<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let [w, h] = self.frame.size.map(|n| n as usize);
        let d = PyDict::new(py);
        let rgba = |px: &[[f32; 4]]| -> PyResult<Bound<'py, PyAny>> {
            let flat: Vec<f32> = px.iter().flatten().copied().collect();
            Ok(PyArray1::from_vec(py, flat).reshape([h, w, 4])?.into_any())
        };
        d.set_item("composite", rgba(&self.frame.composite)?)?;
        if let Some(l) = &self.frame.layers {
            d.set_item("focus.phong", rgba(&l.focus_phong)?)?;
            d.set_item("focus.diffuse", rgba(&l.focus_diffuse)?)?;
            d.set_item("context", rgba(&l.context)?)?;
            let depth = PyArray1::from_vec(py, l.focus_depth.clone()).reshape([h, w])?;
            d.set_item("focus.depth", depth.into_any())?;
        }
        Ok(d)
    }

    /// Where the frame's shading took its gradients from: `"stored"` (a texture made once),
    /// `"at_sample"` (made from the intensity at each shaded sample, for a volume whose intensity
    /// fits `gpu_budget` and whose stored gradients would not) or `"pool"` (made at each shaded
    /// sample from the brick cache's intensity pool), as `vellum render --json` names it.
    #[getter]
    fn gradients(&self) -> &'static str {
        self.gradients
    }

    /// GPU milliseconds per pass of the frame.
    #[getter]
    fn timings<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        for p in &self.frame.passes {
            d.set_item(&p.name, p.ms)?;
        }
        Ok(d)
    }

    /// For a frame drawn through the brick cache, what its streaming did (passes, bricks loaded
    /// and touched, complete, the time to the first and to the complete frame, chunks decoded,
    /// the loaders' and the GPU's busy ms and the share when both were, the main thread's ms
    /// over the passes, ...: `vellum render --json`'s `bricks`); None for a volume in core.
    #[getter]
    fn streaming<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        let Some(r) = &self.stream else {
            return Ok(None);
        };
        let d = PyDict::new(py);
        d.set_item("passes", r.passes)?;
        d.set_item("bricks_loaded", r.bricks_loaded)?;
        d.set_item("bricks_touched", r.bricks_touched)?;
        d.set_item("bricks_evicted", r.bricks_evicted)?;
        d.set_item("capacity", r.capacity)?;
        d.set_item("complete", r.complete)?;
        d.set_item("first_frame_ms", r.first_frame_ms)?;
        d.set_item("total_ms", r.total_ms)?;
        d.set_item("source_mib_per_s", r.source_mib_per_s)?;
        d.set_item("chunks_decoded", r.chunks_decoded)?;
        d.set_item("bytes_streamed", r.bytes_streamed)?;
        d.set_item("host_ms", r.host_ms)?;
        d.set_item("gpu_ms", r.gpu_ms)?;
        d.set_item("both_share", r.both_share)?;
        // The main thread's time over the passes (`--json`'s `bricks.main`).
        d.set_item("record_ms", r.main.record_ms)?;
        d.set_item("gpu_wait_ms", r.main.gpu_wait_ms)?;
        d.set_item("feedback_ms", r.main.feedback_ms)?;
        d.set_item("batch_ms", r.main.batch_ms)?;
        Ok(Some(d))
    }

    #[getter]
    fn size(&self) -> (u32, u32) {
        (self.frame.size[0], self.frame.size[1])
    }

    /// The frame as PNG bytes, for Jupyter.
    fn _repr_png_<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyBytes>> {
        let [w, h] = self.frame.size;
        let mut png = Vec::new();
        image::codecs::png::PngEncoder::new(&mut png)
            .write_image(&self.rgb, w, h, image::ExtendedColorType::Rgb8)
            .map_err(|e| refuse(format!("the frame could not be encoded as PNG ({e})")))?;
        Ok(PyBytes::new(py, &png))
    }
}

use image::ImageEncoder;

/// The keyword options of `render` and `Renderer`: the command line's scene flags in snake case,
/// each filling the field of [`SceneOverrides`] its flag fills, and the session's two.
const OPTIONS: &str = "time, channels, mix, channel_tfs, focus_channel, labels, hide_labels, focus_labels, label_colour, iso, focus, tf, otf, features, camera, view, ortho, pan, size, slices, one_pass, renderer, jitter, ert, no_skip_empty, refine_iso, sampling, background, style, edge_color, edge_opacity, edge_width, edge_threshold, sigma, dog_k, kuwahara_radius, saturation, line_angle, line_threshold, line_bias, line_stride, line_smooth, line_seeded, color_mod, gamma, opacity_mod, stipple, seed, stipple_white, stipple_black, importance_radius, modulate, modulate_lighting, gpu_budget, lod, memory_budget";

/// `scene` with the keyword `options` applied over it by the overrides the command line's flags
/// fill too, and the session's options among them (`gpu_budget` in MiB, `lod`,
/// `memory_budget` in MiB).
fn apply(scene: Scene, options: Option<&Bound<'_, PyDict>>) -> PyResult<(Scene, SessionOptions)> {
    let mut o = SceneOverrides {
        front: Front::Python,
        ..Default::default()
    };
    let mut session = SessionOptions::default();
    for (key, value) in options.into_iter().flat_map(|d| d.iter()) {
        let key: String = key.extract()?;
        let v = Value { key: &key, value };
        let known = v.session(&mut session)?
            || v.labels(&mut o)?
            || v.scene(&mut o)?
            || v.style(&mut o.style)?
            || v.modulation(&mut o.modulation)?;
        if !known {
            return Err(refuse(format!(
                "render has no option {key:?}; expected one of {OPTIONS}"
            )));
        }
    }
    Ok((o.apply(scene).map_err(to_py)?, session))
}

/// One keyword option and its value.
struct Value<'a, 'py> {
    key: &'a str,
    value: Bound<'py, PyAny>,
}

impl<'py> Value<'_, 'py> {
    /// The value as a `T`, or a sentence saying what was expected.
    fn get<T: for<'a> FromPyObject<'a, 'py>>(&self, what: &str) -> PyResult<T> {
        self.value.extract::<T>().map_err(|_| self.bad(what))
    }

    fn bad(&self, what: &str) -> PyErr {
        refuse(format!(
            "{}={} is invalid; expected {what}",
            self.key, self.value
        ))
    }

    /// A tuple of `N` numbers.
    fn floats<const N: usize>(&self, what: &str) -> PyResult<[f32; N]> {
        let v: Vec<f32> = self.get(what)?;
        v.try_into().map_err(|_| self.bad(what))
    }

    /// `gpu_budget`, `lod` and `memory_budget`; whether the key is one of them.
    fn session(&self, session: &mut SessionOptions) -> PyResult<bool> {
        match self.key {
            "gpu_budget" => {
                let mib: f64 = self.get("a number of MiB")?;
                if !(mib.is_finite() && mib > 0.0) {
                    return Err(self.bad("a positive number of MiB"));
                }
                session.gpu_budget_mib = Some(mib);
            }
            "lod" => {
                let lod: String = self.get("\"auto\" or \"finest\"")?;
                session.lod = Lod::parse(&lod).map_err(|_| self.bad("\"auto\" or \"finest\""))?;
            }
            "memory_budget" => {
                let mib: f64 = self.get("a number of MiB")?;
                let opts = std::mem::take(session).with_memory_budget(Some(mib), "memory_budget");
                *session = opts.map_err(|_| self.bad("a number of MiB, at least 1"))?;
            }
            _ => return Ok(false),
        }
        Ok(true)
    }

    /// `labels`, `hide_labels`, `focus_labels` and `label_colour`; whether the key is one of them.
    fn labels(&self, o: &mut SceneOverrides) -> PyResult<bool> {
        let ids = |v: &Self| match v.value.extract::<u32>() {
            Ok(id) => Ok(vec![id]),
            Err(_) => v.get("a label id or a list of ids"),
        };
        match self.key {
            "labels" => o.labels = Some(self.get("a path or a label image's name")?),
            "mix" => o.mix = Some(self.get("\"over\", \"add\" or \"max\"")?),
            "focus_channel" => o.focus_channel = Some(self.get("a channel (0, 1, ...)")?),
            "channel_tfs" | "channel_tf" => {
                let what = "a dict of channel to a preset or a file";
                let tfs: std::collections::BTreeMap<usize, String> = self.get(what)?;
                o.channel_tfs.extend(tfs);
            }
            "hide_labels" => o.hide_labels = Some(ids(self)?),
            "focus_labels" => o.focus_labels = Some(ids(self)?),
            "label_colour" => {
                let what = "a dict of id to \"#RRGGBB\"";
                let colours: std::collections::BTreeMap<u32, String> = self.get(what)?;
                for (id, hex) in colours {
                    let c = vellum_render::render::overrides::parse_label_colour(&format!(
                        "{id}={hex}"
                    ))
                    .map_err(|_| self.bad(what))?;
                    o.label_colours.push(c);
                }
            }
            _ => return Ok(false),
        }
        Ok(true)
    }

    /// The scene's own options; whether the key is one of them.
    fn scene(&self, o: &mut SceneOverrides) -> PyResult<bool> {
        let name = "a name or a path";
        match self.key {
            "iso" => o.iso = Some(self.get("a number")?),
            "time" => o.time = Some(self.get("a time point (0, 1, ...)")?),
            "channels" => {
                o.channels = Some(match self.value.extract::<usize>() {
                    Ok(c) => vec![c],
                    Err(_) => self.get("a channel or a list of channels")?,
                })
            }
            "focus" => o.focus = Some(self.get::<(f64, f64)>("(lo, hi)").map(|(a, b)| [a, b])?),
            "tf" => o.tf = Some(self.get(name)?),
            "otf" => o.otf = Some(self.get(name)?),
            "features" => o.features = Some(self.get(name)?),
            "camera" => {
                let what = "(azimuth, elevation[, distance])";
                let c: Vec<f32> = self.get(what)?;
                if !(2..=3).contains(&c.len()) {
                    return Err(self.bad(what));
                }
                o.camera = Some(CameraAngles {
                    azimuth: c[0],
                    elevation: c[1],
                    distance: c.get(2).copied(),
                });
            }
            "view" => {
                o.view = Some(NamedView::parse(&self.get::<String>("a view name")?).map_err(to_py)?)
            }
            "ortho" => o.ortho = self.get("True or False")?,
            "pan" => o.pan = Some(self.floats("(x, y)")?),
            "size" => {
                o.size = Some(
                    self.get::<(u32, u32)>("(width, height)")
                        .map(|(w, h)| [w, h])?,
                )
            }
            "slices" => o.slices = Some(self.get("a whole number")?),
            "one_pass" => o.one_pass = Some(self.get("True or False")?),
            "renderer" => o.renderer = Some(self.get("\"slicer\" or \"raycast\"")?),
            "jitter" => o.jitter = Some(self.get("a whole number")?),
            "ert" => o.ert = Some(self.get("a number in (0, 1]")?),
            "no_skip_empty" => o.no_skip_empty = self.get("True or False")?,
            "refine_iso" => o.refine_iso = self.get("True or False")?,
            "sampling" => o.sampling = Some(self.get("\"planes\" or \"world-steps\"")?),
            "background" => o.background = Some(self.floats("(r, g, b)")?),
            _ => return Ok(false),
        }
        Ok(true)
    }

    /// The style and its parameters; whether the key is one of them.
    fn style(&self, s: &mut StyleOverrides) -> PyResult<bool> {
        let num = "a number";
        let whole = "a whole number";
        match self.key {
            "style" => {
                s.style = Some(match self.value.extract::<u32>() {
                    Ok(n) => n.to_string(),
                    Err(_) => self.get("a style name or number")?,
                })
            }
            "edge_color" => s.edge_color = Some(self.floats("(r, g, b)")?),
            "edge_opacity" => s.edge_opacity = Some(self.get(num)?),
            "edge_width" => s.edge_width = Some(self.get(whole)?),
            "edge_threshold" => s.edge_threshold = Some(self.get(num)?),
            "sigma" => s.sigma = Some(self.get(num)?),
            "dog_k" => s.dog_k = Some(self.get(num)?),
            "kuwahara_radius" => s.kuwahara_radius = Some(self.get(whole)?),
            "saturation" => s.saturation = Some(self.get(num)?),
            "line_angle" => s.line_angle = Some(self.get(num)?),
            "line_threshold" => s.line_threshold = Some(self.get(num)?),
            "line_bias" => s.line_bias = Some(self.get(num)?),
            "line_stride" => s.line_stride = Some(self.get(whole)?),
            "line_smooth" => {
                let text = match self.value.extract::<f64>() {
                    Ok(r) => r.to_string(),
                    Err(_) => self.get("\"auto\" or a radius in voxels")?,
                };
                s.line_smooth = Some(LineSmooth::parse(&text).map_err(to_py)?);
            }
            "line_seeded" => s.line_seeded = self.get("True or False")?,
            _ => return Ok(false),
        }
        Ok(true)
    }

    /// Importance modulation; whether the key is one of its options.
    fn modulation(&self, m: &mut ModulationOverrides) -> PyResult<bool> {
        match self.key {
            "color_mod" => m.color_mod = Some(self.get("\"raw\" or \"abs\"")?),
            "gamma" => m.gamma = Some(self.get("a number")?),
            "opacity_mod" => m.opacity_mod = Some(self.floats("(t_low, t_high, k_low, k_high)")?),
            "stipple" => m.stipple = Some(self.floats("(t, f)")?),
            "seed" => m.seed = Some(self.get("a whole number")?),
            "stipple_white" => m.stipple_white = Some(self.floats("(r, g, b)")?),
            "stipple_black" => m.stipple_black = Some(self.floats("(r, g, b)")?),
            "importance_radius" => m.importance_radius = Some(self.get("a whole number")?),
            "modulate" => m.modulate = Some(self.get("\"focus\", \"context\" or \"both\"")?),
            "modulate_lighting" => {
                m.modulate_lighting = Some(self.get("\"ambient\" or \"phong\"")?)
            }
            _ => return Ok(false),
        }
        Ok(true)
    }
}

/// What a renderer draws: the scene, the volume given in place of its input (an array), and
/// how the session opens it.
type Source = (Scene, Option<vellum_volume::Volume>, SessionOptions);

/// The scene and, for an array, the volume a renderer draws: a `vellum.Scene`, a scene file's
/// path (`.json`), an input's path or spec (a volume file, a DICOM folder, an OME-Zarr store,
/// `phantom:NAME:N`), or a `vellum.Volume` (the scene of the last two otherwise at the
/// defaults), with `options` over it.
fn source(what: &Bound<'_, PyAny>, options: Option<&Bound<'_, PyDict>>) -> PyResult<Source> {
    let input = vellum_render::render::scene::InputSpec::new;
    if let Ok(v) = what.cast::<crate::PyVolume>() {
        let (scene, session) = apply(Scene::new(input("a numpy array".into())), options)?;
        return Ok((scene, Some(v.get().inner.clone()), session));
    }
    let scene = match what.cast::<PyScene>() {
        Ok(s) => s.borrow().inner.clone(),
        Err(_) => {
            let path = what.extract::<PathBuf>().map_err(|_| {
                refuse("the first argument is not a vellum.Scene, a Volume or a path; expected one of them".into())
            })?;
            let is_scene = path
                .extension()
                .is_some_and(|e| e.eq_ignore_ascii_case("json"));
            match is_scene {
                true => PyScene::load(path)?.inner,
                false => Scene::new(input(path.to_string_lossy().into_owned())),
            }
        }
    };
    let (scene, session) = apply(scene, options)?;
    Ok((scene, None, session))
}

/// What a renderer keeps on the device between frames.
struct Kept {
    session: Session,
    view: View,
    background: [f32; 3],
}

/// A scene prepared once on the device (volume, normals, occlusion or ΔD when the scene needs
/// them, transfer functions) and rendered as many times as asked, e.g. an orbit, with nothing
/// uploaded again. `close()` releases the device memory; a closed renderer refuses to render.
#[pyclass(name = "Renderer", module = "vellum")]
pub struct PyRenderer {
    kept: Mutex<Option<Kept>>,
}

#[pymethods]
impl PyRenderer {
    /// `Renderer(scene_or_volume, **options)`: a `vellum.Scene`, a scene file's path, an
    /// input's path (a volume file, a DICOM folder, an OME-Zarr store, `phantom:NAME:N`) or a
    /// `vellum.Volume`, with options named as the command line's scene flags in snake case
    /// (iso, focus, tf, ..., edge_threshold, ..., stipple, ...: every one `vellum render` takes
    /// but those of its output, and gpu_budget in MiB, lod, memory_budget in MiB). A volume
    /// whose intensity alone exceeds `gpu_budget` is ray-cast through the brick cache, a store
    /// beyond it without reading it whole; one whose intensity fits and whose stored gradients
    /// would not is ray-cast in core, its gradients made at each sample (`Image.gradients`).
    #[new]
    #[pyo3(signature = (scene, **options))]
    fn new(
        py: Python<'_>,
        scene: &Bound<'_, PyAny>,
        options: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Self> {
        Self::prepare(py, source(scene, options)?)
    }

    /// Renders a frame: the scene's view, or with `camera=(azimuth, elevation[, distance])` in
    /// degrees (and radii) and `size=(width, height)` changed for this frame and the next.
    #[pyo3(signature = (camera = None, size = None))]
    fn render(
        &self,
        py: Python<'_>,
        camera: Option<Vec<f32>>,
        size: Option<(u32, u32)>,
    ) -> PyResult<PyImage> {
        let (frame, background, stream, gradients) = self.frame(py, camera, size)?;
        let rgb = to_rgb8(&frame.composite, background);
        Ok(PyImage {
            frame,
            rgb,
            stream,
            gradients,
        })
    }

    /// Releases the device memory the renderer holds; later `render` calls raise vellum.Error.
    fn close(&self) {
        *self.kept.lock().unwrap_or_else(|p| p.into_inner()) = None;
    }
}

impl PyRenderer {
    /// `scene` (its input, or `volume` instead) opened by a session on the process's device.
    fn prepare(py: Python<'_>, (scene, volume, opts): Source) -> PyResult<Self> {
        let kept = on_gpu(py, move |ctx| {
            let session = Session::open(ctx, &scene, volume, &opts)?;
            let oriented = session.prepared.volume().geometry().is_oriented();
            // A volume through the brick cache is ray-cast (the session's rule).
            let (view, _) = session.view(scene.view(oriented)?);
            Ok(Kept {
                session,
                view,
                background: scene.background,
            })
        })?;
        Ok(PyRenderer {
            kept: Mutex::new(Some(kept)),
        })
    }

    /// A frame read back, with the scene's background: the kept view, with `camera` and `size`
    /// changed first when given.
    fn frame(
        &self,
        py: Python<'_>,
        camera: Option<Vec<f32>>,
        size: Option<(u32, u32)>,
    ) -> PyResult<(
        FrameImage,
        [f32; 3],
        Option<vellum_render::render::bricked::StreamReport>,
        &'static str,
    )> {
        let mut slot = self.kept.lock().unwrap_or_else(|p| p.into_inner());
        let kept = slot
            .as_mut()
            .ok_or_else(|| refuse("the renderer is closed; make a new vellum.Renderer".into()))?;
        if let Some(c) = camera {
            if !(2..=3).contains(&c.len()) {
                return Err(refuse(format!(
                    "camera has {} numbers; expected (azimuth, elevation) or (azimuth, elevation, distance)",
                    c.len()
                )));
            }
            kept.view.camera.azimuth_deg = c[0];
            kept.view.camera.elevation_deg = c[1];
            if let Some(&d) = c.get(2) {
                kept.view.camera.distance = d;
            }
        }
        if let Some((w, h)) = size {
            kept.view.size = [w, h];
        }
        let background = kept.background;
        let gradients = kept.session.prepared.gradients().name();
        let (frame, stream) = on_gpu(py, |_| {
            let k = &mut *kept;
            k.view.camera.validate()?;
            k.session.still(&k.view, Default::default())
        })?;
        Ok((frame, background, stream, gradients))
    }
}

/// Object-space lines of the isosurface at `iso` of `volume` (a `vellum.Volume`, a scene or
/// its path) as seen from `camera=(azimuth, elevation[, distance])`: a dict from each of `kinds`
/// ("silhouettes", "suggestive") to a float32 array (N, 2, 3) of segment ends in voxel index
/// coordinates (x, y, z), as `vellum lines` finds them. Other options as for `render`
/// (`line_smooth` is not among them yet).
#[pyfunction]
#[pyo3(signature = (volume, iso, kinds = vec![String::from("silhouettes"), String::from("suggestive")], **options))]
pub fn lines<'py>(
    py: Python<'py>,
    volume: &Bound<'py, PyAny>,
    iso: f64,
    kinds: Vec<String>,
    options: Option<&Bound<'py, PyDict>>,
) -> PyResult<Bound<'py, PyDict>> {
    let wanted: Vec<f32> = kinds
        .iter()
        .map(|k| match k.as_str() {
            "silhouettes" => Ok(0.0),
            "suggestive" => Ok(1.0),
            other => Err(refuse(format!(
                "kind {other:?} is not known; expected \"silhouettes\" or \"suggestive\""
            ))),
        })
        .collect::<PyResult<_>>()?;
    let (mut scene, vol, session) = source(volume, options)?;
    scene.focus = vellum_render::classify::Focus::Iso(iso);
    let style = if wanted.contains(&0.0) {
        "silhouettes"
    } else {
        "suggestive"
    };
    let params = vellum_render::render::style::StyleParams {
        line_both: wanted.len() > 1,
        ..Default::default()
    };
    scene.style = Some(vellum_render::render::scene::StyleSpec {
        style: serde_json::json!(style),
        params,
    });
    let r = PyRenderer::prepare(py, (scene, vol, session))?;
    let (frame, ..) = r.frame(py, None, None)?;
    r.close();
    let (segments, _) = frame.segments.unwrap_or_default();
    let out = PyDict::new(py);
    for (name, kind) in kinds.iter().zip(wanted) {
        let ends: Vec<f32> = segments
            .iter()
            .filter(|s| (s.kind() - kind).abs() < 0.5)
            .flat_map(|s| [s.a[0], s.a[1], s.a[2], s.b[0], s.b[1], s.b[2]])
            .collect();
        let n = ends.len() / 6;
        out.set_item(name, PyArray1::from_vec(py, ends).reshape([n, 2, 3])?)?;
    }
    Ok(out)
}

/// Renders once: `render(scene_or_volume, **options)`, with the arguments of `Renderer`. A
/// scene file renders the pixels `vellum render --scene FILE` writes, and the options are the
/// flags of `vellum render` (`iso=`, `focus=(lo, hi)`, `tf=`, `camera=(az, el)`, `size=(w, h)`,
/// `style=`, `renderer=`, ...).
#[pyfunction]
#[pyo3(signature = (scene, **options))]
pub fn render(
    py: Python<'_>,
    scene: &Bound<'_, PyAny>,
    options: Option<&Bound<'_, PyDict>>,
) -> PyResult<PyImage> {
    let r = PyRenderer::new(py, scene, options)?;
    let image = r.render(py, None, None)?;
    r.close();
    Ok(image)
}

/// Registers the classes and `render` in the module.
pub fn add(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyScene>()?;
    m.add_class::<PyImage>()?;
    m.add_class::<PyRenderer>()?;
    m.add_function(wrap_pyfunction!(render, m)?)?;
    m.add_function(wrap_pyfunction!(lines, m)?)?;
    Ok(())
}
