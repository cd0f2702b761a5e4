"""vellum: illustrative volume rendering on Vulkan, from Python.

Volumes are numpy arrays indexed (z, y, x), as numpy and scipy.ndimage index them; vellum keeps
them with x fastest, which is the same memory. Spacing, origin and direction are given in the
files' (x, y, z) order.

>>> import numpy as np, vellum
>>> v = vellum.Volume(np.zeros((64, 64, 64), np.uint8), spacing=(0.5, 0.5, 1.0))
>>> dd = vellum.importance(v, 5)          # G*V - V, float32, shape (z, y, x)
>>> ao = vellum.occlusion(v, 8)           # ambient occlusion in [0, 1]

Every failure that comes from the input (a file, an array, a parameter) or from the device
raises `vellum.Error`, a `ValueError` whose message is one sentence saying what was expected.
The GPU work runs on one Vulkan device per process (chosen as the command line chooses it:
`VELLUM_DEVICE`, else the best device; `VELLUM_VALIDATION=1` turns the validation layer on),
made on first use; the GIL is released while it runs.
"""

from ._vellum import (
    Error,
    FeatureMap,
    Image,
    Renderer,
    Scene,
    Volume,
    devices,
    importance,
    lines,
    migrate,
    occlusion,
    read,
    remote,
    render,
    spectrum,
    validation_messages,
)

__all__ = [
    "Error",
    "FeatureMap",
    "Image",
    "Renderer",
    "Scene",
    "Volume",
    "devices",
    "importance",
    "lines",
    "migrate",
    "occlusion",
    "read",
    "remote",
    "render",
    "spectrum",
    "validation_messages",
]
