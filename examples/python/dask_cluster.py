"""The importance map and the occlusion of a chunked array on a Dask LocalCluster of worker
processes, each with its own device, against the in-memory calls.

    python examples/python/dask_cluster.py [STORE.ome.zarr] [RADIUS]

With a store (for example from `vellum convert phantom:shepp-logan:128 s.ome.zarr`) it reads
level 0 with dask.array.from_zarr; without one it makes a 64³ array in 32³ chunks.
"""

import sys

import dask.array as da
import numpy as np
from distributed import Client, LocalCluster

import vellum
import vellum.dask


def main():
    radius = int(sys.argv[2]) if len(sys.argv) > 2 else 4
    if len(sys.argv) > 1:
        darr = da.from_zarr(sys.argv[1], component="0")
    else:
        z, y, x = np.mgrid[0:64, 0:64, 0:64].astype(np.float32)
        darr = da.from_array((((x - 32) ** 2 + (y - 32) ** 2 + (z - 32) ** 2) < 400) * 1.0, chunks=32)
    with LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=None) as cluster, Client(cluster):
        dd = vellum.dask.importance(darr, radius).compute()
        ao = vellum.dask.occlusion(darr, radius, method="runs").compute()
    whole = vellum.Volume(np.ascontiguousarray(darr.compute()))
    d_dd = float(np.max(np.abs(dd - vellum.importance(whole, radius))))
    d_ao = float(np.max(np.abs(ao - vellum.occlusion(whole, radius, method="runs"))))
    print(f"{darr.shape} in chunks {darr.chunksize}, R = {radius}, 2 workers: "
          f"max |Δ| against in memory: ΔD {d_dd:.2e}, occlusion {d_ao:.2e}")
    return 0 if d_dd <= 1e-5 * max(float(np.ptp(whole.array)), 1.0) and d_ao <= 1e-5 else 1


if __name__ == "__main__":
    sys.exit(main())
