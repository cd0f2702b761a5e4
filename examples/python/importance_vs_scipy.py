"""The importance map ΔD = G∗V − V beside scipy's: the same kernel (σ = R/3, taps −R..R,
clamped borders), the largest difference as a fraction of the data range, and both times.

    python examples/python/importance_vs_scipy.py [VOLUME.nhdr] [RADIUS]

Without a volume it uses a 96³ array of noise over a ball.
"""

import sys
import time

import numpy as np
from scipy import ndimage

import vellum


def main():
    radius = int(sys.argv[2]) if len(sys.argv) > 2 else 5
    if len(sys.argv) > 1:
        v = vellum.read(sys.argv[1])
    else:
        z, y, x = np.mgrid[0:96, 0:96, 0:96].astype(np.float32)
        ball = ((x - 48) ** 2 + (y - 48) ** 2 + (z - 48) ** 2 < 30**2) * 100.0
        v = vellum.Volume((ball + np.random.default_rng(1).normal(size=ball.shape)).astype(np.float32))
    a = v.array.astype(np.float32)
    vellum.importance(v, radius)  # the device's first use, not timed
    start = time.perf_counter()
    ours = vellum.importance(v, radius)
    t_ours = time.perf_counter() - start
    start = time.perf_counter()
    theirs = ndimage.gaussian_filter(a, sigma=radius / 3.0, truncate=3.0, mode="nearest") - a
    t_scipy = time.perf_counter() - start
    span = float(a.max() - a.min()) or 1.0
    err = float(np.max(np.abs(ours - theirs))) / span
    print(f"{v.shape} R = {radius}: max |vellum - scipy| = {err:.2e} of the range; "
          f"vellum {t_ours * 1e3:.1f} ms (upload and readback included), scipy {t_scipy * 1e3:.1f} ms")
    return 0 if err <= 1e-5 else 1


if __name__ == "__main__":
    sys.exit(main())
