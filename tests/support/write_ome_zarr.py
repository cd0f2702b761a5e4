"""Writes a small uint16 image with Python's ome-zarr package, as another tool would, for
tests/ome_zarr.rs: `write_ome_zarr.py STORE VERSION` (VERSION 0.4 or 0.5) writes the store with
the package's default pyramid and codecs, and the voxels (z, y, x, C order) to STORE.raw."""

import sys

import numpy as np
import zarr
from ome_zarr.format import FormatV04, FormatV05
from ome_zarr.io import parse_url
from ome_zarr.writer import write_image

path, version = sys.argv[1], sys.argv[2]
z, y, x = 12, 10, 14
data = (np.arange(z * y * x, dtype=np.uint16) * 7 % 65521).reshape(z, y, x)
fmt = FormatV04() if version == "0.4" else FormatV05()
store = parse_url(path, mode="w", fmt=fmt).store
root = zarr.group(store=store, zarr_format=fmt.zarr_format)
write_image(data, root, axes="zyx", fmt=fmt, storage_options={"chunks": (5, 4, 6)})
data.tofile(path + ".raw")
