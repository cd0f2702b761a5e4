"""Type stub of vellum's compiled module (python/src/lib.rs); `vellum` re-exports all of it.

Arrays are indexed (z, y, x); spacing, origin and direction are in (x, y, z) order.
"""

import os
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

_Triple = Union[Sequence[float], npt.NDArray[np.floating[Any]]]
_Tuple3 = Tuple[float, float, float]

class Error(ValueError):
    """An input (a file, an array, a parameter) or the device is not what vellum expects.

    The message says what was expected, in one sentence.
    """

class Volume:
    """A 3-D scalar volume: voxels, spacing, origin and direction.

    `array` is a 3-D array indexed (z, y, x). uint8, uint16, int16 and float32 are kept as they
    are; bool becomes uint8, int8 int16, and other integer and float types float32 (integers
    beyond 2**24 and float64 values round). Any layout is accepted (it is copied C-contiguous);
    complex, string, object and date arrays, and NaN or infinite voxels, are refused.
    `spacing` (default (1, 1, 1)) and `origin` (default (0, 0, 0)) are (x, y, z), as volume
    files give them; `direction` is a 3x3 rotation, row by row, whose column c is the direction
    of index axis c (x first), by default the identity. Bad input raises `vellum.Error`.
    """

    def __new__(
        cls,
        array: npt.ArrayLike,
        spacing: Optional[_Triple] = None,
        origin: Optional[_Triple] = None,
        direction: Optional[Union[Sequence[Sequence[float]], npt.NDArray[np.floating[Any]]]] = None,
    ) -> "Volume": ...
    @property
    def array(self) -> npt.NDArray[Any]:
        """The voxels, indexed (z, y, x), of the volume's dtype: a read-only view, no copy."""
    @property
    def spacing(self) -> _Tuple3:
        """The size of a voxel along x, y and z."""
    @property
    def origin(self) -> _Tuple3:
        """The position of voxel (0, 0, 0), as (x, y, z)."""
    @property
    def direction(self) -> Tuple[_Tuple3, _Tuple3, _Tuple3]:
        """The direction matrix, row by row; column c is the direction of index axis c."""
    @property
    def shape(self) -> Tuple[int, int, int]:
        """The array's shape, (z, y, x)."""
    @property
    def dtype(self) -> np.dtype[Any]:
        """The voxels' dtype: uint8, uint16, int16 or float32."""

def read(
    path: Union[str, "os.PathLike[str]"],
    time: Optional[int] = None,
    channel: Optional[int] = None,
    level: Optional[int] = None,
) -> Volume:
    """Reads a volume as the command line does.

    NRRD (.nrrd, .nhdr), NIfTI (.nii, .nii.gz), MetaImage (.mhd, .mha), a folder of one DICOM
    series, or an OME-Zarr store (its full resolution, or its pyramid's `level` with that
    level's spacing: a look at a store too large to read whole; `time` and `channel` pick one
    of its time points and channels, as `--time` and `--channel` do).
    """

def remote(
    cache_dir: Optional[Union[str, "os.PathLike[str]"]] = None,
    cache_mib: Optional[int] = None,
    timeout_s: Optional[float] = None,
) -> None:
    """How stores on a server (http:// and https:// URLs, read wherever a path is) are read.

    As the command line's --cache-dir, --cache-mib and --http-timeout: the chunk cache's folder
    (default $XDG_CACHE_HOME/vellum/http), its size in MiB (0 keeps none; default 1024), and the
    seconds without a byte before a request is tried again (default 20, three more tries).
    """

def devices() -> List[Dict[str, Any]]:
    """The Vulkan devices, one dict each.

    Keys: `index`, `name`, `type`, `api_version`, `driver`, `rejected` (why vellum cannot use
    the device, or None) and `chosen` (whether GPU work runs on it: `VELLUM_DEVICE`, an index
    or part of a name, else the best usable device).
    """

def importance(volume: Volume, radius: int) -> npt.NDArray[np.float32]:
    """The importance map ΔD = G∗V − V of `volume` on the GPU, float32, indexed (z, y, x).

    G is a Gaussian of `radius` voxels (1 to 32): σ = R/3, taps −R..R, clamped borders, i.e.
    `scipy.ndimage.gaussian_filter(v, R / 3, truncate=3, mode="nearest") - v`, in the volume's
    data units.
    """

def occlusion(
    volume: Volume, radius: int, mapping: str = "ramp", method: str = "auto"
) -> npt.NDArray[np.float32]:
    """Ambient occlusion of `volume`: the mean visibility over each voxel's neighbourhood.

    Values in [0, 1], float32, indexed (z, y, x). `mapping`: "ramp", "gaussian",
    "truncated:T0,T1" (fractions of the data range) or "tf:FILE.json". `method`: "auto",
    "runs", "fft-gpu" or "fft-cpu"; all give the same values. `range`: the data values that
    normalise to 0 and 1 when `volume` is a block of a larger grid; by default its own.
    """

def spectrum(
    volume: Volume,
    radius: int,
    bins: int = 64,
    mapping: str = "ramp",
    method: str = "auto",
) -> npt.NDArray[np.uint32]:
    """The occlusion spectrum: the 2-D histogram of (intensity, occlusion) over the voxels.

    uint32, indexed (occlusion bin, intensity bin), `bins` (1 to 4096) along each. Intensity
    bins span the volume's min..max, occlusion bins 0..1.
    """

def validation_messages() -> tuple[int, int]:
    """The validation layer's (errors, warnings) on the process's device so far; (0, 0) before
    the device is made or with validation off (VELLUM_VALIDATION=1 turns it on)."""

class Scene:
    """A scene: input, classification, focus, camera, size, style and the rest, as the JSON
    scene file holds them (`vellum render --save-scene`)."""

    @staticmethod
    def load(path: str | os.PathLike[str]) -> Scene: ...
    @staticmethod
    def from_json(text: str) -> Scene: ...
    def to_json(self) -> str: ...
    def save(self, path: str | os.PathLike[str]) -> None: ...

class Image:
    """A rendered frame."""

    @property
    def rgba(self) -> npt.NDArray[np.uint8]:
        """(height, width, 4) over the scene's background, alpha 255: the pixels of `vellum render`'s PNG."""
    @property
    def layers(self) -> dict[str, npt.NDArray[np.float32]]:
        """composite, and for two levels focus.phong, focus.diffuse, context (H, W, 4) and focus.depth (H, W)."""
    @property
    def timings(self) -> dict[str, float]:
        """GPU milliseconds per pass."""
    @property
    def size(self) -> tuple[int, int]: ...
    def _repr_png_(self) -> bytes: ...
    @property
    def streaming(self) -> dict[str, float | int | bool | None] | None:
        """For a frame drawn through the brick cache, what its streaming did (passes,
        bricks_loaded, bricks_touched, bricks_evicted, capacity, complete, first_frame_ms
        (None: no coarse frame is drawn for a still frame), total_ms, source_mib_per_s,
        chunks_decoded, bytes_streamed, host_ms (the loaders busy) and gpu_ms, both_share
        (of the frame, both busy), and the main thread's ms over the passes: record_ms,
        gpu_wait_ms, feedback_ms, batch_ms); None for a volume in core."""
    @property
    def gradients(self) -> str:
        """Where the shading's gradients came from: "stored", "at_sample" (made from the
        intensity at each shaded sample: its intensity fits gpu_budget, its stored gradients
        would not) or "pool" (the brick cache's), as `vellum render --json` names it."""

class Renderer:
    """A scene prepared once on the device and rendered many times (an orbit) with nothing
    uploaded again. `close()` releases its device memory."""

    def __init__(self, scene: Scene | Volume | str | os.PathLike[str], **options: object) -> None:
        """A scene, a scene file's path (.json), an input's path (a volume file, a DICOM folder,
        an OME-Zarr store, "phantom:NAME:N") or a Volume, with options named as `vellum
        render`'s scene flags in snake case, each meaning what its flag means (docs/cli.md):
        time and channels (a store's time point and channel), iso, focus=(lo, hi), tf (default "auto": the grey ramp over the histogram's window), otf,
        features (with otf: the two composed), camera=(az, el[, dist]) (without dist the volume
        is framed), view, ortho, pan=(x, y), size=(w, h), slices, one_pass, renderer, and the ray
        caster's jitter, ert, no_skip_empty, refine_iso, sampling (these need
        renderer="raycast"), background=(r, g, b), style and its edge_color=(r, g, b),
        edge_opacity, edge_width, edge_threshold, sigma, dog_k, kuwahara_radius, saturation,
        line_angle, line_threshold, line_bias, line_stride, line_smooth, line_seeded, the
        modulation's color_mod, gamma, opacity_mod=(t_l, t_h, k_l, k_h), stipple=(t, f), seed,
        stipple_white, stipple_black, importance_radius, modulate, modulate_lighting; and
        gpu_budget (MiB of GPU memory for the volume's textures; a volume whose intensity alone
        needs more is ray-cast through the brick cache, a store without reading it whole, and one
        whose intensity fits and whose stored gradients would not is ray-cast in core with its
        gradients made at each sample; default: half the device's largest heap), lod ("auto" or "finest": the levels a bricked frame samples),
        memory_budget (MiB of host memory for a streamed volume's decoded chunks and the bricks
        waiting for the GPU; default 1024)."""
    def render(
        self,
        camera: tuple[float, float] | tuple[float, float, float] | None = None,
        size: tuple[int, int] | None = None,
    ) -> Image: ...
    def close(self) -> None: ...

def render(scene: Scene | Volume | str | os.PathLike[str], **options: object) -> Image:
    """Renders once, with the arguments of `Renderer`: a scene file gives the pixels `vellum
    render --scene FILE` writes, and the options those of the same flags."""

def lines(
    volume: Volume | Scene | str | os.PathLike[str],
    iso: float,
    kinds: list[str] = ["silhouettes", "suggestive"],
    **options: object,
) -> dict[str, npt.NDArray[np.float32]]:
    """Object-space lines of the isosurface at `iso`: per kind, (N, 2, 3) segment ends in voxel
    index coordinates (x, y, z), as `vellum lines` finds them. Options as for `render`."""

class FeatureMap:
    """A feature map: features (label, private interval, colour) over the context's range, as
    `vellum migrate` writes it."""

    @staticmethod
    def load(path: str | os.PathLike[str]) -> FeatureMap: ...
    @staticmethod
    def from_json(text: str) -> FeatureMap: ...
    def to_json(self) -> str: ...
    def save(self, path: str | os.PathLike[str]) -> None: ...
    @property
    def features(self) -> list[tuple[str, tuple[float, float], tuple[float, float, float]]]: ...

def migrate(
    volume: Volume,
    label: str,
    seeds: list[tuple[int, int, int]] | None = None,
    window: tuple[float, float] | None = None,
    mask: Volume | None = None,
    connectivity: int = 26,
    features: FeatureMap | None = None,
) -> tuple[Volume, FeatureMap]:
    """Migrates the feature given by `mask`, or grown from `seeds` (x, y, z) within `window`,
    into a private density interval, its fuzzy boundary rebuilt: the feature volume and the
    map, as `vellum migrate` writes them."""
