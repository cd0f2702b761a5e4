"""Rendering from Python (issue 28): a scene gives the pixels `vellum render --scene` writes, bit
for bit; a Renderer keeps its scene on the device through 200 frames without the resident set
growing; a closed renderer refuses in one sentence."""

import json
import os
import pathlib
import subprocess

import numpy as np
import pytest

import vellum

ROOT = pathlib.Path(__file__).resolve().parents[2]


def cli():
    """The command line binary `cargo test` or `cargo build` left in target/."""
    for profile in ["debug", "release"]:
        exe = ROOT / "target" / profile / "vellum"
        if exe.is_file():
            return exe
    if os.environ.get("CI") == "true":
        pytest.fail("no target/*/vellum; CI builds it before the Python tests")
    pytest.skip("no target/*/vellum; build it first")


def scene_file(tmp_path, *flags):
    path = tmp_path / "scene.json"
    args = [str(cli()), "render", "phantom:shepp-logan:64", "--tf", "grey", "--size", "96x80"]
    subprocess.run(args + list(flags) + ["--save-scene", str(path)], check=True, capture_output=True)
    return path


def rss_kib():
    for line in open("/proc/self/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return 0


@pytest.mark.parametrize(
    "flags",
    [("--iso", "0.9"), ("--iso", "0.9", "--style", "canny"), ("--one-pass", "--renderer", "raycast")],
)
def test_a_scene_renders_the_command_lines_pixels(tmp_path, flags):
    from PIL import Image as PilImage

    path = scene_file(tmp_path, *flags)
    png = tmp_path / "cli.png"
    subprocess.run([str(cli()), "render", "--scene", str(path), "--out", str(png)], check=True, capture_output=True)
    theirs = np.asarray(PilImage.open(png).convert("RGB"))
    image = vellum.render(str(path))
    ours = image.rgba
    assert ours.shape == (80, 96, 4) and ours.dtype == np.uint8
    np.testing.assert_array_equal(ours[..., :3], theirs)
    assert (ours[..., 3] == 255).all()
    assert ours[..., :3].max() > 0, "the frame is not empty"
    # The same through a Scene object, and its JSON round trip.
    scene = vellum.Scene.load(str(path))
    again = vellum.render(vellum.Scene.from_json(scene.to_json()))
    np.testing.assert_array_equal(again.rgba, ours)


def test_an_image_has_its_layers_timings_and_a_png():
    scene = vellum.Scene.from_json('{"version": 1, "input": {"path": "phantom:shepp-logan:48"}, "focus": {"iso": 0.9}, "size": [64, 48]}')
    image = vellum.render(scene)
    assert image.size == (64, 48)
    layers = image.layers
    assert set(layers) == {"composite", "focus.phong", "focus.diffuse", "context", "focus.depth"}
    assert layers["focus.depth"].shape == (48, 64)
    assert np.isfinite(layers["focus.depth"]).any(), "the iso surface was hit"
    assert image.timings and all(ms >= 0 for ms in image.timings.values())
    assert image._repr_png_()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_renderer_keeps_its_scene_through_200_frames():
    scene = vellum.Scene.from_json('{"version": 1, "input": {"path": "phantom:shepp-logan:48"}, "focus": {"iso": 0.9}, "size": [64, 64]}')
    r = vellum.Renderer(scene)
    first = r.render(camera=(0, 20)).rgba
    for i in range(20):
        r.render(camera=(i * 18, 20))
    before = rss_kib()
    for i in range(200):
        r.render(camera=(i * 1.8, 20))
    grown = (rss_kib() - before) / 1024
    assert grown <= 5.0, f"the resident set grew {grown:.1f} MiB over 200 frames"
    np.testing.assert_array_equal(r.render(camera=(0, 20)).rgba, first)
    r.close()
    with pytest.raises(vellum.Error, match="closed") as raised:
        r.render()
    assert "\n" not in str(raised.value)


def test_options_named_as_the_flags_render_a_volume_as_the_command_line_does(tmp_path):
    from PIL import Image as PilImage

    nrrd = tmp_path / "phantom.nrrd"
    subprocess.run([str(cli()), "convert", "phantom:shepp-logan:64", str(nrrd)], check=True, capture_output=True)
    flags = ["--iso", "0.9", "--tf", "grey", "--camera", "30,20", "--size", "96x80", "--style", "canny"]
    png = tmp_path / "cli.png"
    subprocess.run([str(cli()), "render", str(nrrd), *flags, "--out", str(png)], check=True, capture_output=True)
    theirs = np.asarray(PilImage.open(png).convert("RGB"))
    v = vellum.read(str(nrrd))
    image = vellum.render(v, iso=0.9, tf="grey", camera=(30, 20), size=(96, 80), style="canny")
    np.testing.assert_array_equal(image.rgba[..., :3], theirs)
    # The same volume from its numpy array.
    again = vellum.render(vellum.Volume(v.array, spacing=v.spacing, origin=v.origin), iso=0.9,
                          tf="grey", camera=(30, 20), size=(96, 80), style=3)
    np.testing.assert_array_equal(again.rgba, image.rgba)
    ray = vellum.render(v, iso=0.9, size=(64, 64), renderer="raycast", jitter=1)
    assert ray.rgba[..., :3].max() > 0


def test_every_scene_flag_of_the_command_line_is_a_keyword():
    """The flags and the keywords fill one type of overrides: each scene flag `vellum render
    --help` lists is a keyword, spelled in snake case, and a bad value for it is refused in one
    sentence that names it, never as an unknown option."""
    import re

    help_text = subprocess.run([str(cli()), "render", "--help"], check=True, capture_output=True,
                               text=True).stdout
    flags = set(re.findall(r"^\s+(?:-\w, )?--([a-z][a-z0-9-]*)", help_text, re.M))
    # Not scene options: where the frame goes, what to report, the scene file itself, how to
    # read a headerless input (Python passes arrays), the flags of the command's own run, and
    # how stores on a server are read (vellum.remote's keywords).
    not_scene = {"out", "exr", "json", "composite", "scene", "save-scene", "help", "verbose",
                 "device", "raw-dims", "raw-type", "big-endian", "offset", "raw-spacing",
                 "raw-origin", "max-wait-ms", "progress-frames", "memory-budget", "cache-dir",
                 "cache-mib", "http-timeout", "first-frame", "time-whole-frame"}
    keywords = sorted(f.replace("-", "_") for f in flags - not_scene)
    assert {"iso", "style", "edge_threshold", "stipple", "gpu_budget", "ert", "pan"} <= set(keywords)
    v = vellum.Volume(np.zeros((8, 8, 8), np.float32))
    for key in keywords:
        with pytest.raises(vellum.Error) as raised:
            vellum.render(v, **{key: object()})
        message = str(raised.value)
        assert "has no option" not in message, f"--{key} has no keyword: {message}"
        assert key in message and "\n" not in message, message


def test_the_ray_options_say_how_to_ask_for_the_ray_caster_in_python_terms():
    v = vellum.Volume(np.zeros((8, 8, 8), np.float32))
    with pytest.raises(vellum.Error, match='add renderer="raycast"'):
        vellum.render(v, jitter=1)
    with pytest.raises(vellum.Error, match="edge_threshold has no effect on style 4"):
        vellum.render(v, iso=0.5, style=4, edge_threshold=0.2)


def test_style_modulation_and_camera_keywords_render_as_their_flags(tmp_path):
    from PIL import Image as PilImage

    nrrd = tmp_path / "phantom.nrrd"
    subprocess.run([str(cli()), "convert", "phantom:shepp-logan:48", str(nrrd)], check=True,
                   capture_output=True)
    flags = ["--iso", "0.9", "--camera", "40,25", "--pan", "0.1,0", "--ortho", "--size", "72x64",
             "--style", "dog", "--edge-threshold", "0.01", "--edge-color", "0.2,0,0",
             "--renderer", "raycast", "--ert", "0.9", "--color-mod", "abs", "--gamma", "2"]
    png = tmp_path / "cli.png"
    subprocess.run([str(cli()), "render", str(nrrd), *flags, "--out", str(png)], check=True,
                   capture_output=True)
    theirs = np.asarray(PilImage.open(png).convert("RGB"))
    ours = vellum.render(str(nrrd), iso=0.9, camera=(40, 25), pan=(0.1, 0), ortho=True,
                         size=(72, 64), style="dog", edge_threshold=0.01, edge_color=(0.2, 0, 0),
                         renderer="raycast", ert=0.9, color_mod="abs", gamma=2)
    np.testing.assert_array_equal(ours.rgba[..., :3], theirs)


def test_an_unknown_or_bad_option_is_one_sentence():
    v = vellum.Volume(np.zeros((8, 8, 8), np.float32))
    with pytest.raises(vellum.Error, match='has no option "colour"') as raised:
        vellum.render(v, colour="red")
    assert "\n" not in str(raised.value)
    with pytest.raises(vellum.Error, match="expected \\(width, height\\)"):
        vellum.render(v, size="big")
    with pytest.raises(vellum.Error, match="renderer"):
        vellum.render(v, renderer="pathtracer")


def test_lines_are_the_command_lines_segments(tmp_path):
    import json

    nrrd = tmp_path / "torus.nrrd"
    subprocess.run([str(cli()), "convert", "phantom:torus:64", str(nrrd)], check=True, capture_output=True)
    flags = ["--iso", "0.5", "--camera", "20,35", "--size", "128x128", "--kind", "both"]
    out = subprocess.run([str(cli()), "lines", str(nrrd), *flags, "--out", str(tmp_path / "l.png"), "--json"],
                         check=True, capture_output=True, text=True)
    report = json.loads(out.stdout)
    v = vellum.read(str(nrrd))
    got = vellum.lines(v, 0.5, camera=(20, 35), size=(128, 128))
    assert set(got) == {"silhouettes", "suggestive"}
    assert len(got["silhouettes"]) == report["silhouette_segments"] > 0
    assert len(got["suggestive"]) == report["suggestive_segments"]
    s = got["silhouettes"]
    assert s.shape[1:] == (2, 3) and s.dtype == np.float32
    assert (s >= -1).all() and (s <= 64).all(), "ends lie in the voxel grid"
    only = vellum.lines(v, 0.5, kinds=["silhouettes"], camera=(20, 35), size=(128, 128))
    assert list(only) == ["silhouettes"] and len(only["silhouettes"]) == len(s)
    with pytest.raises(vellum.Error, match="not known"):
        vellum.lines(v, 0.5, kinds=["creases"])


def test_otf_with_features_composes_as_the_command_line_does(tmp_path):
    """otf= and features= together compose the two classifications (issue 29), as --otf with
    --features does on the command line."""
    from PIL import Image as PilImage

    examples = ROOT / "examples"
    volume = examples / "features" / "nested_sphere.nrrd"
    features = examples / "features" / "nested_sphere.features.json"
    otf = examples / "nested_otf.json"
    png = tmp_path / "cli.png"
    subprocess.run([str(cli()), "render", str(volume), "--features", str(features), "--otf", str(otf),
                    "--camera", "0,20", "--size", "64x64", "--out", str(png)], check=True, capture_output=True)
    theirs = np.asarray(PilImage.open(png).convert("RGB"))
    scene = vellum.Scene.from_json(json.dumps({"version": 1, "input": {"path": str(volume)}}))
    image = vellum.render(scene, features=str(features), otf=str(otf), camera=(0, 20), size=(64, 64))
    np.testing.assert_array_equal(image.rgba[..., :3], theirs)
    alone = vellum.render(scene, otf=str(otf), camera=(0, 20), size=(64, 64))
    assert np.abs(alone.rgba.astype(int) - image.rgba.astype(int)).max() > 0, "the features add their colour"


def test_a_store_beyond_its_budget_streams_through_the_session(tmp_path):
    """Issue 39: a path is an input, opened as the command line opens it. A store whose textures
    exceed gpu_budget goes through the brick cache and the ray caster, and its complete frame at
    level 0 equals the command line's (pixel for pixel) and the in-core render (within a mean of
    0.5/255); one whose intensity fits and whose stored gradients would not is drawn in core with
    them made at each sample, the same frame (within 0.05/255)."""
    from PIL import Image as PilImage

    store = tmp_path / "s.ome.zarr"
    subprocess.run([str(cli()), "convert", "phantom:shepp-logan:96", str(store), "--chunk", "32"],
                   check=True, capture_output=True)
    flags = ["--iso", "0.9", "--tf", "grey", "--camera", "30,20,2.5", "--size", "96x96", "--renderer", "raycast"]
    png = tmp_path / "cli.png"
    out = subprocess.run([str(cli()), "render", str(store), *flags, "--gpu-budget", "1", "--lod", "finest",
                          "--out", str(png), "--json"], check=True, capture_output=True, text=True)
    assert json.loads(out.stdout)["bricks"]["complete"] is True
    theirs = np.asarray(PilImage.open(png).convert("RGB"))
    options = dict(iso=0.9, tf="grey", camera=(30, 20, 2.5), size=(96, 96), renderer="raycast")
    image = vellum.render(str(store), gpu_budget=1, lod="finest", **options)
    streaming = image.streaming
    assert streaming is not None and streaming["complete"]
    assert streaming["bricks_loaded"] > streaming["capacity"], "a one-MiB pool is refilled"
    assert 0.0 <= streaming["both_share"] <= 1.0 and streaming["chunks_decoded"] > 0
    assert streaming["host_ms"] > 0, "the same keys as render --json's bricks"
    main = [streaming[k] for k in ("record_ms", "gpu_wait_ms", "feedback_ms", "batch_ms")]
    assert all(ms > 0 for ms in main) and sum(main) <= streaming["total_ms"], main
    np.testing.assert_array_equal(image.rgba[..., :3], theirs)
    whole = vellum.render(str(store), **options)
    assert whole.streaming is None, "96³ fits the default budget"
    diff = np.abs(whole.rgba.astype(float) - image.rgba.astype(float))[..., :3]
    assert diff.mean() <= 0.5, f"mean {diff.mean():.3f}/255"
    assert (whole.gradients, image.gradients) == ("stored", "pool")
    # Between its intensity (1.7 MiB) and its stored gradients (8.4 MiB): in core, the gradients
    # made at each sample, and the frame of the stored ones.
    sampled = vellum.render(str(store), gpu_budget=4, **options)
    assert sampled.streaming is None and sampled.gradients == "at_sample"
    diff = np.abs(whole.rgba.astype(float) - sampled.rgba.astype(float))[..., :3]
    assert diff.mean() <= 0.05, f"mean {diff.mean():.4f}/255"
    # A level of the pyramid, read whole from Python: half the voxels along each axis, twice as
    # far apart; and a level the store lacks, or a level of a file, in one sentence.
    whole, half = vellum.read(str(store)), vellum.read(str(store), level=1)
    assert half.array.shape == tuple(n // 2 for n in whole.array.shape)
    assert half.spacing == tuple(2 * s for s in whole.spacing)
    np.testing.assert_allclose(half.array.mean(), whole.array.mean(), rtol=0.01)
    for bad, phrase in [(str(store), "level 9 is not one of them"), (str(png), "is not one")]:
        with pytest.raises(vellum.Error, match=phrase) as raised:
            vellum.read(bad, level=9)
        assert "\n" not in str(raised.value)
    # Through 1 MiB of host memory (a fraction of the store's 3.4 MiB of chunks): the same frame.
    tight = vellum.render(str(store), gpu_budget=1, lod="finest", memory_budget=1, **options)
    np.testing.assert_array_equal(tight.rgba, image.rgba)
    assert tight.streaming["chunks_decoded"] >= streaming["chunks_decoded"]
    # A Renderer keeps the pools and the bricks between frames.
    r = vellum.Renderer(str(store), gpu_budget=1, lod="finest", **options)
    np.testing.assert_array_equal(r.render().rgba, image.rgba)
    assert r.render(camera=(60, 20, 2.5)).rgba[..., :3].max() > 0
    r.close()
    for bad, phrase in [(dict(gpu_budget=0), "gpu_budget"), (dict(lod="sharpest"), "lod"),
                        (dict(gpu_budget=0.1), "gpu_budget. 0.2 or more"),
                        (dict(memory_budget=0.5), "memory_budget=0.5 is invalid")]:
        with pytest.raises(vellum.Error, match=phrase) as raised:
            vellum.render(str(store), **bad)
        assert "\n" not in str(raised.value)


def test_auto_shows_a_mask():
    """A 0/1 ball rendered with the default `auto` transfer function is white and lit, as the
    command line draws it (before: all black, and a dim blob under iso=0.5)."""
    z, y, x = np.mgrid[:64, :64, :64]
    ball = ((x - 31.5) ** 2 + (y - 31.5) ** 2 + (z - 31.5) ** 2 <= 400).astype(np.uint8)
    for iso in [None, 0.5]:
        options = {} if iso is None else {"iso": iso}
        rgb = vellum.render(vellum.Volume(ball), size=(96, 96), **options).rgba[..., :3]
        lit = (rgb.max(axis=2) > 30).mean()
        assert lit > 0.05 and rgb.max() >= 200, (iso, lit, rgb.max())


def _time_series(root):
    """A (t, c, z, y, x) Zarr v2 store written by hand: 3 time points of a growing ball in
    channel 0 and a slab in channel 1, 24³ u16."""
    (root / "0").mkdir(parents=True)
    (root / ".zgroup").write_text('{"zarr_format": 2}')
    axes = [{"name": n} for n in "tczyx"]
    scale = [{"type": "scale", "scale": [1.0] * 5}]
    (root / ".zattrs").write_text(json.dumps({"multiscales": [
        {"version": "0.4", "axes": axes, "datasets": [{"path": "0", "coordinateTransformations": scale}]}]}))
    n = 24
    (root / "0" / ".zarray").write_text(json.dumps({
        "zarr_format": 2, "shape": [3, 2, n, n, n], "chunks": [1, 1, n, n, n], "dtype": "<u2",
        "compressor": None, "fill_value": 0, "order": "C", "filters": None, "dimension_separator": "/"}))
    z, y, x = np.mgrid[:n, :n, :n] - 11.5
    for t in range(3):
        for c in range(2):
            inside = (x**2 + y**2 + z**2 <= (4 + 3 * t) ** 2) if c == 0 else (z + 11.5 < n / 2)
            chunk = root / "0" / str(t) / str(c) / "0" / "0"
            chunk.mkdir(parents=True)
            inside.astype("<u2").tofile(chunk / "0")


def test_time_and_channels_pick_from_a_store_as_the_flags_do(tmp_path):
    from PIL import Image as PilImage

    store = tmp_path / "series.ome.zarr"
    _time_series(store)
    png = tmp_path / "cli.png"
    subprocess.run([str(cli()), "render", str(store), "--time", "2", "--channels", "0", "--size", "64x64",
                    "--out", str(png)], check=True, capture_output=True)
    theirs = np.asarray(PilImage.open(png).convert("RGB"))
    ours = vellum.render(str(store), time=2, channels=0, size=(64, 64)).rgba[..., :3]
    np.testing.assert_array_equal(ours, theirs)
    assert (vellum.render(str(store), time=2, channels=[0], size=(64, 64)).rgba[..., :3] == ours).all()
    with pytest.raises(vellum.Error, match="holds 3 time points; pick one with `time`"):
        vellum.render(str(store), channels=0)
    with pytest.raises(vellum.Error, match="time point 5 does not exist"):
        vellum.render(str(store), time=5, channels=0)
    # read picks the same way: channel 1 is the lower half, time point 2 the largest ball.
    assert vellum.read(store, time=1, channel=1).array.sum() == 24 * 24 * 12
    balls = [vellum.read(store, time=t, channel=0).array.sum() for t in range(3)]
    assert balls[0] < balls[1] < balls[2], balls


def test_a_store_on_a_server_reads_and_renders_as_from_disk(tmp_path):
    """Issue 42: an http:// URL is an input wherever a path is; vellum.remote sets the chunk cache."""
    import functools
    import http.server
    import threading

    store = tmp_path / "s.ome.zarr"
    subprocess.run([str(cli()), "convert", "phantom:shepp-logan:40", str(store), "--chunk", "16"],
                   check=True, capture_output=True)
    class Quiet(http.server.SimpleHTTPRequestHandler):
        def log_message(self, *args):
            pass

    handler = functools.partial(Quiet, directory=str(tmp_path))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        url = f"http://127.0.0.1:{server.server_address[1]}/s.ome.zarr"
        cache = tmp_path / "cache"
        vellum.remote(cache_dir=str(cache), cache_mib=64, timeout_s=5)
        np.testing.assert_array_equal(vellum.read(url).array, vellum.read(str(store)).array)
        written = sum(1 for _ in (store / "0" / "c").rglob("*") if _.is_file())
        assert len(list(cache.iterdir())) == written, "one cache file per chunk of level 0"
        options = dict(size=(48, 48), renderer="raycast")
        np.testing.assert_array_equal(vellum.render(url, **options).rgba, vellum.render(str(store), **options).rgba)
        with pytest.raises(vellum.Error, match="timeout_s"):
            vellum.remote(timeout_s=0)
    finally:
        vellum.remote()
        server.shutdown()


def two_balls(tmp_path, n, r):
    """An n³ label volume of two balls of radius r on the x axis (ids 3 and 7, at 10/32 and 22/32
    of it), written as seg.nrrd in tmp_path, and their mask as a Volume."""
    z, y, x = np.mgrid[0:n, 0:n, 0:n]
    labels = np.zeros((n, n, n), np.uint8)
    for id, cx in [(3, 10 * n // 32), (7, 22 * n // 32)]:
        labels[(x - cx) ** 2 + (y - n // 2) ** 2 + (z - n // 2) ** 2 <= r * r] = id
    path = tmp_path / "seg.nrrd"
    header = f"NRRD0004\ntype: uint8\ndimension: 3\nsizes: {n} {n} {n}\nencoding: raw\n\n"
    path.write_bytes(header.encode() + labels.tobytes())
    return vellum.Volume((labels > 0).astype(np.float32)), path


def test_segments_of_a_label_volume_are_keywords(tmp_path):
    """Issue 42: labels=, hide_labels=, focus_labels= and label_colour= draw segments as the flags do."""
    import re

    v, path = two_balls(tmp_path, 32, 6)
    options = dict(size=(64, 64), camera=(0, 90), ortho=True)
    red = vellum.render(v, labels=str(path), hide_labels=0, label_colour={3: "#ff0000", 7: "#0000ff"},
                        **options).rgba.astype(int)
    lit = red[..., :3].max(-1) > 40
    reds = lit & (red[..., 0] > 2 * red[..., 2])
    blues = lit & (red[..., 2] > 2 * red[..., 0])
    assert reds.sum() > 50 and blues.sum() > 50 and (reds | blues).sum() >= 0.9 * lit.sum()
    only7 = vellum.render(v, labels=str(path), hide_labels=[0, 3], label_colour={7: "#0000ff"}, **options)
    lit7 = only7.rgba[..., :3].max(-1) > 40
    assert 0 < lit7.sum() < 0.6 * lit.sum() and not (lit7 & reds).any()
    focus = vellum.render(v, labels=str(path), hide_labels=0, focus_labels=7, style=14, **options)
    assert focus.rgba[..., :3].max() > 40
    with pytest.raises(vellum.Error, match=re.escape("focus_labels picks segments of a label volume; add labels=PATH|NAME")):
        vellum.render(v, focus_labels=3)
    with pytest.raises(vellum.Error, match="label_colour"):
        vellum.render(v, labels=str(path), label_colour={3: "red"})


def test_segments_of_a_volume_beyond_its_budget_go_through_the_brick_cache(tmp_path):
    """Issue 42: labels= beside a volume whose textures exceed gpu_budget: its bricks carry the
    segment indices, and the frame at level 0 is the frame in core."""
    v, path = two_balls(tmp_path, 64, 10)
    options = dict(labels=str(path), hide_labels=[0, 3], size=(64, 64), camera=(0, 90), ortho=True)
    core = vellum.render(v, **options).rgba.astype(int)
    paged = vellum.render(v, gpu_budget=1, lod="finest", **options).rgba.astype(int)
    # In core a label volume keeps stored gradients; the pool's are made at each sample: the same
    # up to single pixels where a gradient is nearly flat (tests/gradients.rs).
    diff = np.abs(core - paged)[..., :3]
    assert diff.mean() <= 0.05 and (diff > 1).mean() <= 0.001, f"mean {diff.mean():.4f}"
    lit = paged[..., :3].max(-1) > 40
    assert 150 < lit.sum() < 500, "segment 7 alone: one disc of radius 10"


def test_channels_are_mixed_by_keywords(tmp_path):
    """Issue 42: channels=, mix=, channel_tfs= and focus_channel= mix a store's channels as the flags do."""
    if subprocess.run(["python3", "-c", "import ome_zarr"], capture_output=True).returncode != 0:
        pytest.skip("ome-zarr is missing")
    script = pathlib.Path(__file__).parents[2] / "tests" / "support" / "write_ome_zarr_channels.py"
    store = tmp_path / "c.zarr"
    subprocess.run(["python3", str(script), str(store), "0.5"], check=True, capture_output=True)
    options = dict(size=(48, 48), camera=(0, 90), ortho=True)
    ab = vellum.render(str(store), channels=[0, 1], mix="add", **options).rgba.astype(int)
    ba = vellum.render(str(store), channels=[1, 0], mix="add", **options).rgba.astype(int)
    assert np.abs(ab - ba).max() <= 1
    assert tuple(ab[24, 24, :3]) == (255, 0, 255), "red and blue added in the middle third"
    cli_png = tmp_path / "cli.png"
    subprocess.run([str(cli()), "render", str(store), "--channels", "1,0", "--channel-tf", "0=grey",
                    "--focus-channel", "0", "--size", "48x48", "--camera", "0,90", "--ortho",
                    "--out", str(cli_png)], check=True, capture_output=True)
    from PIL import Image as PilImage
    theirs = np.asarray(PilImage.open(cli_png).convert("RGB"))
    ours = vellum.render(str(store), channels=[1, 0], channel_tfs={0: "grey"}, focus_channel=0, **options)
    np.testing.assert_array_equal(ours.rgba[..., :3], theirs)
    with pytest.raises(vellum.Error, match="mix"):
        vellum.render(str(store), channels=0, mix="add")


def test_channels_of_a_store_beyond_its_budget_mix_through_the_brick_cache(tmp_path):
    """Issue 42: a two-channel store whose textures exceed gpu_budget mixes its channels through
    the brick cache; under over, add and max its complete frame at level 0 is the in-core frame
    within a mean of 0.5/255."""
    torus = tmp_path / "torus.nrrd"
    subprocess.run([str(cli()), "convert", "phantom:torus:96", str(torus)], check=True, capture_output=True)
    store = tmp_path / "two.ome.zarr"
    subprocess.run([str(cli()), "convert", "phantom:shepp-logan:96", str(store), "--chunk", "32",
                    "--add-channel", str(torus)], check=True, capture_output=True)
    options = dict(channels=[0, 1], size=(64, 64), camera=(30, 20))
    for mix in ["over", "add", "max"]:
        whole = vellum.render(str(store), mix=mix, **options)
        paged = vellum.render(str(store), mix=mix, gpu_budget=3, lod="finest", **options)
        assert whole.streaming is None and paged.streaming["complete"], mix
        assert paged.streaming["bricks_loaded"] > paged.streaming["capacity"], "the pool is refilled"
        diff = np.abs(whole.rgba.astype(float) - paged.rgba.astype(float))[..., :3]
        assert whole.rgba[..., :3].max() > 100, mix
        # (In core the channels keep stored gradients; the pool's are made at each sample.)
        assert diff.mean() <= 0.5 and diff.max() <= 64, f"{mix}: mean {diff.mean():.3f}, max {diff.max()}"
