"""`vellum.dask` on a LocalCluster of two worker processes equals the in-memory call (issue 28):
blocks of 24³ with their overlap, each computed in a worker's own process on its own device."""

import numpy as np
import pytest

import vellum
import vellum.dask

da = pytest.importorskip("dask.array")
distributed = pytest.importorskip("distributed")


@pytest.fixture(scope="module")
def client():
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None)
    with distributed.Client(cluster) as c:
        yield c
    cluster.close()


def volume():
    z, y, x = np.mgrid[0:40, 0:48, 0:56].astype(np.float32)
    ball = ((x - 28) ** 2 + (y - 24) ** 2 + (z - 20) ** 2 < 15**2).astype(np.float32)
    noise = np.random.default_rng(7).normal(size=ball.shape).astype(np.float32)
    return 100 * ball + noise


def test_dask_importance_equals_the_in_memory_call(client):
    a = volume()
    darr = da.from_array(a, chunks=24)
    assert darr.numblocks == (2, 2, 3)
    ours = vellum.dask.importance(darr, 5).compute()
    whole = vellum.importance(vellum.Volume(a), 5)
    np.testing.assert_array_equal(ours, whole)
    # The workers' own devices ran with validation on, and it stayed silent.
    assert set(client.run(vellum.validation_messages).values()) == {(0, 0)}


def test_dask_occlusion_equals_the_in_memory_call(client):
    a = volume()
    darr = da.from_array(a, chunks=24)
    ours = vellum.dask.occlusion(darr, 6, method="runs").compute()
    whole = vellum.occlusion(vellum.Volume(a), 6, method="runs")
    span = 1.0  # occlusion lies in [0, 1]
    assert float(np.max(np.abs(ours - whole))) <= 1e-5 * span
    assert 0.0 < float(ours.mean()) < 1.0


def test_a_2d_dask_array_is_refused():
    with pytest.raises(ValueError, match="expected 3 axes"):
        vellum.dask.importance(da.zeros((4, 4), chunks=2), 1)
