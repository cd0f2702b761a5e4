#!/usr/bin/env python3
"""CPU peer for the importance map: scipy.ndimage.gaussian_filter with vellum's kernel.

Usage: scipy_peer.py VOLUME.f32 X Y Z R REPEAT
Reads a raw little-endian float32 volume (x fastest), computes delta_d = G*V - V with
sigma = R/3, truncate = 3 (so the kernel has taps -R..R), mode 'nearest' (clamped borders), and
prints {"median_ms": ..., "runs_ms": [...]} for the filter plus the subtraction.
With --out PATH it also writes delta_d as raw float32, for conformance checks.
"""
import json
import sys
import time

import numpy as np
from scipy import ndimage


def main():
    args = [a for a in sys.argv[1:] if not a.startswith("--out=")]
    out = [a[6:] for a in sys.argv[1:] if a.startswith("--out=")]
    path, x, y, z, r, repeat = args[0], int(args[1]), int(args[2]), int(args[3]), int(args[4]), int(args[5])
    v = np.fromfile(path, dtype="<f4").reshape((z, y, x))
    sigma = r / 3.0
    runs = []
    dd = None
    for _ in range(max(1, repeat)):
        t0 = time.perf_counter()
        dd = ndimage.gaussian_filter(v, sigma=sigma, truncate=3.0, mode="nearest") - v
        runs.append((time.perf_counter() - t0) * 1e3)
    if out:
        dd.astype("<f4").tofile(out[0])
    print(json.dumps({"median_ms": float(np.median(runs)), "runs_ms": runs}))


if __name__ == "__main__":
    main()
