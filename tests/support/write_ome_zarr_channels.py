"""Writes a two-channel (c, z, y, x) uint16 image with Python's ome-zarr package and NGFF omero
metadata, as a microscope's converter would, for tests/channels.rs: `write_ome_zarr_channels.py
STORE VERSION`. 32^3 voxels; along x, the first third holds channel 0 only, the middle third both
channels, the last third channel 1 only, each 1000 in the slab 8 <= z < 24 and 0 elsewhere.
omero: channel 0 red, channel 1 blue, both with the window 0..500 (so 1000 is at full colour).

`write_ome_zarr_channels.py STORE VERSION 8`: eight channels instead, channel k holding 1000 in
the slab only in the band 4k <= x < 4k + 4, each in its own omero colour (COLOURS below)."""

import sys

import numpy as np
import zarr
from ome_zarr.format import FormatV04, FormatV05
from ome_zarr.io import parse_url
from ome_zarr.writer import add_metadata, write_image

COLOURS = ["FF0000", "00FF00", "0000FF", "FFFF00", "FF00FF", "00FFFF", "FFFFFF", "FF8000"]

path, version = sys.argv[1], sys.argv[2]
count = int(sys.argv[3]) if len(sys.argv) > 3 else 2
n = 32
data = np.zeros((count, n, n, n), np.uint16)
if count == 2:
    data[0, 8:24, :, :22] = 1000
    data[1, 8:24, :, 11:] = 1000
else:
    for k in range(count):
        data[k, 8:24, :, 4 * k:4 * k + 4] = 1000
fmt = FormatV04() if version == "0.4" else FormatV05()
store = parse_url(path, mode="w", fmt=fmt).store
root = zarr.group(store=store, zarr_format=fmt.zarr_format)
write_image(data, root, axes="czyx", fmt=fmt, storage_options={"chunks": (1, 16, 16, 16)})
window = {"start": 0, "end": 500, "min": 0, "max": 65535}
names = ["red", "blue"] if count == 2 else COLOURS[:count]
colours = ["FF0000", "0000FF"] if count == 2 else COLOURS[:count]
omero = {"channels": [
    {"color": c, "window": window, "active": True, "label": name}
    for c, name in zip(colours, names)
]}
add_metadata(root, {"omero": omero}, fmt=fmt)
