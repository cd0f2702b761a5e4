"""Issue 42's time-series goal: a 100-time-point 128^3 uint16 OME-Zarr store played from a local
disk, counting load and frame. `time_series.py VELLUM [TIMES] [N] [SIZE]` writes the store
(TIMES time points of N^3 voxels, chunks of 64^3, zarr's default compression) with Python's
ome-zarr, then times

- `vellum render STORE --time all --out DIR/ --size SIZExSIZE --renderer raycast`: every time point
  read, put on the GPU, drawn and written as a PNG, one after another, and
- `vellum view STORE --time 0 --play --bench F --json` under the caller's display: the viewer
  playing, time points loaded on its workers (the next one read ahead) while frames are drawn;
  its report counts the time points shown.

It prints one JSON object: time points per second for each, with the store's size. The content is
a ball moving along x whose brightness swings by a factor of three over 25 time points, on a
faint ramp: a picture that flickers if the time points are not drawn on one intensity scale."""

import json
import math
import os
import subprocess
import sys
import tempfile
import time

import numpy as np
import zarr
from ome_zarr.format import FormatV04
from ome_zarr.io import parse_url
from ome_zarr.writer import write_image


def write_store(path, times, n):
    z, y, x = np.mgrid[0:n, 0:n, 0:n].astype(np.float32)
    ramp = (40.0 * x / n).astype(np.float32)
    data = np.zeros((times, n, n, n), np.uint16)
    for t in range(times):
        cx = n * (0.25 + 0.5 * t / max(times - 1, 1))
        amp = 1000.0 * (1.0 + 0.5 * math.sin(2.0 * math.pi * t / 25.0))
        d2 = (x - cx) ** 2 + (y - n / 2) ** 2 + (z - n / 2) ** 2
        ball = amp * np.exp(-d2 / (2.0 * (n / 8) ** 2))
        data[t] = np.clip(ball + ramp, 0, 65535).astype(np.uint16)
    fmt = FormatV04()
    store = parse_url(path, mode="w", fmt=fmt).store
    root = zarr.group(store=store, zarr_format=fmt.zarr_format)
    write_image(data, root, axes="tzyx", fmt=fmt, scaler=None,
                storage_options={"chunks": (1, 64, 64, 64)})


def main():
    vellum = sys.argv[1]
    times = int(sys.argv[2]) if len(sys.argv) > 2 else 100
    n = int(sys.argv[3]) if len(sys.argv) > 3 else 128
    size = int(sys.argv[4]) if len(sys.argv) > 4 else 512
    report = {"times": times, "voxels": n, "size": size}
    with tempfile.TemporaryDirectory() as tmp:
        store = os.path.join(tmp, "series.ome.zarr")
        write_store(store, times, n)
        out = os.path.join(tmp, "frames")
        start = time.perf_counter()
        subprocess.run([vellum, "render", store, "--time", "all", "--out", out + "/",
                        "--size", f"{size}x{size}", "--renderer", "raycast"],
                       check=True, stdout=subprocess.DEVNULL)
        seconds = time.perf_counter() - start
        report["render_all_s"] = round(seconds, 2)
        report["render_time_points_per_s"] = round(times / seconds, 2)
        if os.environ.get("DISPLAY"):
            frames = int(os.environ.get("FRAMES", "300"))
            got = subprocess.run([vellum, "view", store, "--time", "0", "--play", "--bench",
                                  str(frames), "--json", "--no-vsync", "--size",
                                  f"{size + 330}x{size}"],
                                 check=True, capture_output=True, text=True)
            bench = json.loads(got.stdout[got.stdout.index("{"):])
            report["view"] = {k: bench.get(k) for k in
                              ("fps", "render_size", "time_points_shown", "time_points_per_s")}
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
