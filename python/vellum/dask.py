"""The passes on chunked arrays: Dask computes `vellum.importance` and `vellum.occlusion` block by
block with `dask.array.map_overlap`, each block widened by the filter's reach (the radius) on
every side and cropped back, so a cluster computes them on data that no one machine holds, for
example `dask.array.from_zarr` of an OME-Zarr level.

The overlap is the reach R, and there is no padding past the array's edges (`boundary="none"`):
a block at the edge sees the grid's edge, as the whole array's pass does, so every voxel equals
the in-memory call. The occlusion normalises every block over the whole array's range, which is
computed first (one reduction).
"""

import numpy as np

from ._vellum import Volume, importance as _importance, occlusion as _occlusion


def _as_dask(darr):
    import dask.array as da

    if not isinstance(darr, da.Array):
        darr = da.asarray(darr)
    if darr.ndim != 3:
        raise ValueError(f"a {darr.ndim}-D array was given; expected 3 axes (z, y, x)")
    return darr


def importance(darr, radius, spacing=None):
    """ΔD = G∗V − V of a 3-D Dask array (z, y, x), block by block; float32, chunked as `darr`."""
    darr = _as_dask(darr)
    r = int(radius)

    def block(b):
        return _importance(Volume(np.ascontiguousarray(b), spacing=spacing), r)

    return darr.map_overlap(block, depth=r, boundary="none", dtype=np.float32, trim=True)


def occlusion(darr, radius, mapping="ramp", method="auto", spacing=None):
    """Ambient occlusion of a 3-D Dask array (z, y, x), block by block, every block normalised
    over the whole array's range; float32 in [0, 1], chunked as `darr`."""
    import dask

    darr = _as_dask(darr)
    r = int(radius)
    lo, hi = dask.compute(darr.min(), darr.max())
    span = (float(lo), float(hi))

    def block(b):
        v = Volume(np.ascontiguousarray(b), spacing=spacing)
        return _occlusion(v, r, mapping=mapping, method=method, range=span)

    return darr.map_overlap(block, depth=r, boundary="none", dtype=np.float32, trim=True)
