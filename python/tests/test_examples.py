"""The examples under examples/python run and say what they promise (issue 28)."""

import pathlib
import subprocess
import sys

import pytest

EXAMPLES = pathlib.Path(__file__).resolve().parents[2] / "examples" / "python"


def run(name, *args):
    out = subprocess.run([sys.executable, str(EXAMPLES / name), *map(str, args)], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr + out.stdout
    return out.stdout


def test_the_orbit_writes_its_frames(tmp_path):
    printed = run("orbit.py", tmp_path, 6)
    frames = sorted(tmp_path.glob("frame_*.png"))
    assert len(frames) == 6 and "6 frames" in printed
    assert all(f.read_bytes()[:4] == b"\x89PNG" for f in frames)
    assert len({f.read_bytes() for f in frames}) == 6, "the camera moved"


def test_importance_beside_scipy_agrees():
    assert "of the range" in run("importance_vs_scipy.py")


def test_the_dask_example_agrees_with_memory(tmp_path):
    pytest.importorskip("distributed")
    assert "2 workers" in run("dask_cluster.py")
    # On a level of an OME-Zarr store, read by dask.array.from_zarr.
    from test_render import cli

    store = tmp_path / "s.ome.zarr"
    subprocess.run([str(cli()), "convert", "phantom:shepp-logan:48", str(store), "--chunk", "16"],
                   check=True, capture_output=True)
    assert "in chunks (16, 16, 16)" in run("dask_cluster.py", store, 3)
