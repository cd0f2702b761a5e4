"""An orbit rendered through one vellum.Renderer: the scene goes to the device once, and each
frame only moves the camera. Writes FRAMES PNGs into OUT_DIR.

    python examples/python/orbit.py OUT_DIR [FRAMES] [SCENE.json]

Without a scene file it orbits a two-level, Canny-styled Shepp-Logan phantom.
"""

import pathlib
import sys
import time

import vellum

PHANTOM = """{"version": 1, "input": {"path": "phantom:shepp-logan:96"}, "focus": {"iso": 0.9},
"style": {"style": "canny"}, "size": [256, 256]}"""


def main():
    out = pathlib.Path(sys.argv[1])
    frames = int(sys.argv[2]) if len(sys.argv) > 2 else 36
    scene = vellum.Scene.load(sys.argv[3]) if len(sys.argv) > 3 else vellum.Scene.from_json(PHANTOM)
    out.mkdir(parents=True, exist_ok=True)
    renderer = vellum.Renderer(scene)
    start = time.perf_counter()
    for i in range(frames):
        image = renderer.render(camera=(i * 360.0 / frames, 20.0))
        (out / f"frame_{i:03d}.png").write_bytes(image._repr_png_())
    seconds = time.perf_counter() - start
    renderer.close()
    print(f"{frames} frames in {seconds:.2f} s ({frames / seconds:.1f} frames/s, PNG encoding included) into {out}")


if __name__ == "__main__":
    main()
