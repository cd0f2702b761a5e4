"""Feature maps from Python (issue 28): `vellum.migrate` gives the feature volume and map that
`vellum migrate` writes, and `render(features=...)` paints the feature in its colour."""

import json
import pathlib
import subprocess

import numpy as np
import pytest

import vellum
from test_render import cli


def test_migrate_is_the_command_lines(tmp_path):
    nested = tmp_path / "nested.nrrd"
    subprocess.run([str(cli()), "convert", "phantom:nested:64", str(nested)], check=True, capture_output=True)
    out = tmp_path / "feature.nrrd"
    subprocess.run([str(cli()), "migrate", str(nested), "--seed", "46,32,32", "--window", "0.7:0.8",
                    "--label", "sphere", "--out", str(out)], check=True, capture_output=True)
    theirs = vellum.read(str(out)).array
    their_map = json.loads((tmp_path / "feature.features.json").read_text())
    v = vellum.read(str(nested))
    migrated, fmap = vellum.migrate(v, "sphere", seeds=[(46, 32, 32)], window=(0.7, 0.8))
    np.testing.assert_array_equal(migrated.array, theirs)
    (label, interval, colour), = fmap.features
    assert label == "sphere" and interval[0] > float(v.array.max())
    assert json.loads(fmap.to_json())["context_range"] == their_map["context_range"]
    # Rendered with its map, the feature takes its colour.
    path = tmp_path / "map.json"
    fmap.save(str(path))
    rgba = vellum.render(migrated, features=str(path), one_pass=True, camera=(0, 20), size=(96, 96)).rgba
    c = np.array(colour) / max(colour)
    hue = rgba[..., :3].astype(float)
    lit = hue.sum(axis=2) > 60
    cos = (hue[lit] @ c) / (np.linalg.norm(hue[lit], axis=1) * np.linalg.norm(c))
    assert (cos > 0.98).sum() > 50, "the feature's colour is in the picture"
    # A second feature is appended to the map; its label must be new.
    with pytest.raises(vellum.Error, match="exists already"):
        vellum.migrate(migrated, "sphere", seeds=[(46, 32, 32)], window=(0.7, 0.8), features=fmap)
    with pytest.raises(vellum.Error, match="no feature given"):
        vellum.migrate(v, "x")
