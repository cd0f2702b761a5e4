#!/usr/bin/env python3
"""Peer for `vellum bench occlusion --peer scipy`: ball ambient occlusion by FFT convolution with
scipy.signal.fftconvolve, O = (M * B) / (1 * B) over the volume (neighbours outside are left out of
sum and count, as in vellum).

usage: ao_peer.py MAPPED.f32 NX NY NZ R OUT.f32
MAPPED is the visibility M per voxel, float32, x fastest. Prints {"median_ms": ...} and writes O.
"""
import json
import sys
import time

import numpy as np
from scipy import signal


def ball(radius, dims):
    # Offsets beyond N - 1 along an axis never land in the volume, so the kernel is cut there.
    ex = [min(radius, n - 1) for n in dims]  # x, y, z
    z, y, x = np.ogrid[-ex[2]:ex[2] + 1, -ex[1]:ex[1] + 1, -ex[0]:ex[0] + 1]
    return (x * x + y * y + z * z <= radius * radius).astype(np.float32)


def main():
    path, nx, ny, nz, r, out = sys.argv[1], *map(int, sys.argv[2:6]), sys.argv[6]
    m = np.fromfile(path, dtype=np.float32).reshape(nz, ny, nx)
    b = ball(r, (nx, ny, nz))
    start = time.perf_counter()
    num = signal.fftconvolve(m, b, mode="same")
    den = signal.fftconvolve(np.ones_like(m), b, mode="same")
    o = np.clip(num / np.maximum(den, 1e-30), 0.0, 1.0).astype(np.float32)
    ms = (time.perf_counter() - start) * 1e3
    o.tofile(out)
    print(json.dumps({"median_ms": ms}))


if __name__ == "__main__":
    main()
