"""Writes an image with a label image beside it, with Python's ome-zarr package, as another tool
would, for tests/labels.rs: `write_ome_zarr_labels.py STORE VERSION` writes a 24 x 20 x 16 image
(z, y, x) whose labels/seg holds ids 0, 7 and 300 as uint32 (300 outside uint8 on purpose), with
the NGFF image-label colour of 7 set to pure red, and the labels (z, y, x, C order, uint32) to
STORE.labels.raw."""

import sys

import numpy as np
import zarr
from ome_zarr.format import FormatV04, FormatV05
from ome_zarr.io import parse_url
from ome_zarr.writer import write_image, write_labels

path, version = sys.argv[1], sys.argv[2]
z, y, x = 16, 20, 24
zz, yy, xx = np.meshgrid(np.arange(z), np.arange(y), np.arange(x), indexing="ij")
labels = np.zeros((z, y, x), np.uint32)
labels[(xx - 7) ** 2 + (yy - 10) ** 2 + (zz - 8) ** 2 <= 25] = 7
labels[(xx - 17) ** 2 + (yy - 10) ** 2 + (zz - 8) ** 2 <= 25] = 300
image = (labels > 0).astype(np.uint16) * 1000
fmt = FormatV04() if version == "0.4" else FormatV05()
store = parse_url(path, mode="w", fmt=fmt).store
root = zarr.group(store=store, zarr_format=fmt.zarr_format)
write_image(image, root, axes="zyx", fmt=fmt, storage_options={"chunks": (8, 10, 12)})
colors = [{"label-value": 7, "rgba": [255, 0, 0, 255]}]
write_labels(labels, root, name="seg", axes="zyx", fmt=fmt, label_metadata={"colors": colors})
labels.tofile(path + ".labels.raw")
