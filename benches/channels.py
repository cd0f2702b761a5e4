#!/usr/bin/env python3
"""Issue 42's channel goal, as ratios in one run: the frame time of 2, 4 and 8 channels of a uint16
store mixed in one ray against its first channel alone.

usage: channels.py VELLUM N SIZE [REPEATS]   (e.g. target/release/vellum 256 512 5)

Writes an N^3 store of eight channels with Python's ome-zarr package (each channel a few soft
Gaussian blobs, so that every channel has structure), then times `vellum render --json` on it:
`--channels 0` (the one-channel renderer, skipping on), `0,1`, `0,1,2,3` and `0,...,7` under each
mix (a binary that mixes fewer refuses the last: "refused"), and
`0,1` with channel 1 transparent (the cost of mixing apart from what channel 1 adds to the
picture). The figure is the median GPU time of the `raycast` pass over REPEATS rounds, each
round running every row once in turn. Prints a Markdown table.
"""
import json
import statistics
import subprocess
import sys
import tempfile

import numpy as np
import zarr
from ome_zarr.format import FormatV05
from ome_zarr.io import parse_url
from ome_zarr.writer import write_image


def store(path, n):
    rng = np.random.default_rng(42)
    z, y, x = np.ogrid[0:n, 0:n, 0:n]
    data = np.zeros((8, n, n, n), np.uint16)
    for c in range(8):
        field = np.zeros((n, n, n), np.float32)
        for _ in range(6):
            cz, cy, cx = rng.uniform(0.2, 0.8, 3) * n
            r = rng.uniform(0.06, 0.15) * n
            field += np.exp(-((x - cx) ** 2 + (y - cy) ** 2 + (z - cz) ** 2) / (2 * r * r))
        data[c] = (np.clip(field, 0, 1) * 4000).astype(np.uint16)
    fmt = FormatV05()
    root = zarr.group(store=parse_url(path, mode="w", fmt=fmt).store, zarr_format=fmt.zarr_format)
    chunk = min(n, 64)
    write_image(data, root, axes="czyx", fmt=fmt, storage_options={"chunks": (1, chunk, chunk, chunk)})


def raycast_ms(vellum, path, size, flags):
    out = subprocess.run([vellum, "render", path, "--size", f"{size}x{size}", "--camera", "30,20",
                          "--renderer", "raycast", "--json", "--out", path + ".png", *flags],
                         capture_output=True, text=True)
    if out.returncode != 0:
        return None
    return json.loads(out.stdout)["passes"]["raycast"]


def main():
    vellum, n, size = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    repeats = int(sys.argv[4]) if len(sys.argv) > 4 else 5
    with tempfile.TemporaryDirectory() as tmp:
        path = f"{tmp}/c.zarr"
        store(path, n)
        # The cost of mixing itself, apart from what the other channels add to the picture:
        # channel 1 present but transparent, so the rays see what channel 0 alone shows.
        clear = f"{tmp}/clear.json"
        with open(clear, "w") as f:
            f.write('{"points": [{"x": 0, "rgba": [0, 0, 0, 0]}, {"x": 1, "rgba": [0, 0, 0, 0]}]}')
        rows = [("0", "—", ["--channels", "0"])]
        for channels in ["0,1", "0,1,2,3", "0,1,2,3,4,5,6,7"]:
            for mix in ["over", "add", "max"]:
                rows.append((channels, mix, ["--channels", channels, "--mix", mix]))
        rows.append(("0,1 (1 transparent)", "over", ["--channels", "0,1", "--channel-tf", f"1={clear}"]))
        # Rounds of every row in turn, so that a machine that drifts moves every row alike.
        times = [[] for _ in rows]
        for _ in range(repeats):
            for i, (_, _, flags) in enumerate(rows):
                times[i].append(raycast_ms(vellum, path, size, flags))
        one = statistics.median(times[0])
        print(f"| channels | mix | raycast ms (median of {repeats}) | against channel 0 alone |")
        print("|---|---|---|---|")
        for (channels, mix, _), ts in zip(rows, times):
            if None in ts:
                print(f"| {channels} | {mix} | refused | — |")
                continue
            ms = statistics.median(ts)
            print(f"| {channels} | {mix} | {ms:.2f} | {ms / one:.2f}× |")


if __name__ == "__main__":
    main()
