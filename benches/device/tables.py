#!/usr/bin/env python3
"""Writes BENCHMARKS.md's GPU tables from the JSON that benches/device/run.sh brought back.

    python3 benches/device/tables.py DIR [BENCHMARKS.md]

DIR (or the results.tar run.sh leaves) holds device.txt and one JSON file per bench (table1, render, styles, lines, occlusion,
occlusion512, vtk, ...); a missing one leaves its rows saying so. The text between the two marker lines
`<!-- bench-device:begin -->` and `<!-- bench-device:end -->` is replaced (appended when absent);
nothing else in the file is touched. Standard library only.
"""

import json
import re
import pathlib
import sys
import tarfile
import tempfile

BEGIN, END = "<!-- bench-device:begin -->", "<!-- bench-device:end -->"
# The heading of the one section this script writes between the markers.
GENERATED = "## On a GPU: every bench through `make bench-device`"

# Datasheet memory bandwidth by device name, the yardstick of the bandwidth-bound passes
# (the bench's image copy is no bound on NVIDIA's driver: see the Table 1 section).
PEAK_TBS = {"H100 80GB HBM3": 3.35, "H200": 4.8}


def load(d, name):
    p = d / f"{name}.json"
    return json.loads(p.read_text()) if p.exists() else None


def peak_tbs(device):
    return next((v for k, v in PEAK_TBS.items() if k in device), None)


def fmt(x, nd=2):
    return "—" if x is None else f"{x:,.{nd}f}"


def render_rows(render, data, size):
    if not render:
        return None
    for r in render["rows"]:
        if data in r["data"].lower().replace(" ", "") and r["size"] == size:
            return r
    return None


def bandwidths(r, ms4):
    """TB/s of gauss_x, y, z (one float volume read, one written) and subtract (two read, one
    written) from their ms, counting the volume's voxels × 4 bytes."""
    n = r["dims"][0] * r["dims"][1] * r["dims"][2] * 4
    return [k * n / (ms * 1e-3) / 1e12 for k, ms in zip((2, 2, 2, 3), ms4)]


def median(xs):
    xs = sorted(xs)
    return xs[len(xs) // 2] if xs else None


def goals(dev, t1, render, styles, lines, occ, occ512, styles_ray=None, bricked=None, vtk=None):
    """The issue's goals, one row each: what was measured, the goal, met or not."""
    rows = []

    def add(what, measured, goal, met):
        rows.append((what, measured, goal, "—" if met is None else ("**met**" if met else "not met")))

    for data, name, fps_goal in (("head", "CT head", 500), ("engine", "engine", 200)):
        r = render_rows(render, data, 1024)
        ms = r["raycast_two_level_ms"] if r else None
        add(f"ray caster, {name}, two levels, 1024²",
            f"{fmt(ms)} ms ({fmt(1000 / ms, 0) if ms else '—'} fps)", f"≥ {fps_goal} fps",
            None if ms is None else 1000 / ms >= fps_goal)
    for label, st in (("ray caster", styles_ray), ("slicer", styles)):
        s11 = [r for r in (st or {}).get("rows", []) if r["style"] == 11 and r["size"] == 1024
               and "head" in r["data"].lower()]
        ms = s11[0]["frame_ms"] if s11 else None
        add(f"style 11 with lines, CT head, 1024², {label} (the frame's GPU passes; no window)",
            f"{fmt(ms)} ms ({fmt(1000 / ms, 0) if ms else '—'} fps)", "≥ 60 fps",
            None if ms is None else 1000 / ms >= 60)
    both = [r for r in (lines or {}).get("rows", []) if "head" in r["data"].lower()
            and r["kind"] == "both" and r["mode"] == "all"]
    ms = both[0]["gpu_ms"] if both else None
    add("object-space lines, CT head, every cell, both kinds", f"{fmt(ms)} ms", "≤ 5 ms",
        None if ms is None else ms <= 5)
    peak = peak_tbs(dev)
    # Sustained: the passes recorded back to back on the volume uploaded once (the device kept
    # busy); single: each pass once per run of Table 1, between uploads and readbacks, when the
    # GPU has lowered its clocks (see the section's notes).
    for label, key in (("sustained", "sustained_ms"), ("single runs", None)):
        for r in [r for r in (t1 or {}).get("rows", []) if r["case"] == "ct-head"]:
            ms4 = r.get(key) if key else r["gauss_ms"] + [r["subtract_ms"]]
            if ms4 is None:
                continue
            bw = bandwidths(r, ms4)
            pct = [b / peak * 100 for b in bw] if peak else [None] * 4
            add(f"gauss_x, y, z, subtract, CT head R = {r['radius']} ({label})",
                " / ".join(f"{b:.2f} TB/s ({fmt(p, 0)} %)" for b, p in zip(bw, pct)),
                "≥ 70 % of peak each", None if peak is None else min(pct) >= 70)
    for label, table, goal_ms in (("bonsai 256³", occ, 100), ("512³", occ512, 1000)):
        ms = None
        for row in (table or {}).get("rows", []):
            if row["radius"] == 64:
                ms = next((c["ms"] for c in row["cells"] if c["method"] == "fft-gpu"), None)
        add(f"AO fft-gpu, R = 64, {label}", f"{fmt(ms, 1)} ms", f"≤ {goal_ms / 1000:g} s",
            None if ms is None else ms <= goal_ms)
    rows += goals43(t1, render, bricked)
    rows_b = {b["case"]: median(b["ms"]) for b in (bricked or {}).get("rows", [])}
    core = rows_b.get("core_skip")
    # The fastest way of looking bricks up that the run measured.
    # (A case whose renders all failed has no median and is left out.)
    best = min(((ms, c) for c, ms in rows_b.items() if c.startswith("bricked_") and ms is not None),
               default=(None, None))
    ratio = best[0] / core if core and best[0] else None
    add("bricked ray caster against in-core, Shepp–Logan 256³ at level 0 through a pool 0.99× "
        "its size, two levels, 1024² (median of 5 renders)",
        f"{fmt(best[0], 3)} ms ({best[1]}) against {fmt(core, 3)} ms: {fmt(ratio)}×", "≤ 1.2× (issue 43)",
        None if ratio is None else ratio <= 1.2)
    peer = (vtk or {}).get("peer")
    if peer:
        # Ours over VTK's frame time, each timed the same way: wall ms from a frame's recording
        # (VTK: Render) to its completion, one frame at a time.
        # A size VTK gave no time for (NaN, written as null) is left out.
        ratios = [(r["size"], r["raycast_wall_ms"] / r["vtk_ms"]) for r in peer["rows"]
                  if r.get("vtk_ms") and r.get("raycast_wall_ms")]
        add(f"VTK's GPU ray caster on the same GPU ({peer['vtk_renderer']}), CT head, one pass, "
            "wall ms of a frame alone",
            ", ".join(f"{n}²: {x:.3f}×" for n, x in ratios) or "no size timed", "ours ≤ 0.25×",
            all(x <= 0.25 for _, x in ratios) if ratios else None)
    else:
        add("VTK's GPU ray caster on the same GPU", "not run (pack VTK: `make bench-device`)",
            "ours ≤ 0.25×", None)
    return rows


# Empty-space skipping against none (issue 43): the bricked case's pairs, two levels and one pass.
SKIP_PAIRS = (("Shepp–Logan 256³", "core"), ("CT head", "head"), ("engine", "engine"), ("chest", "chest"))


def goals43(t1, render, bricked):
    """Issue 43's goals: no fixed cost in a frame, skipping that never loses, passes at the
    bandwidth of a plain copy measured in the same run."""
    rows = []

    def add(what, measured, goal, met):
        rows.append((what, measured, goal, "—" if met is None else ("**met**" if met else "not met")))

    for size in (64, 256):
        r = render_rows(render, "head", size)
        ms = r["raycast_one_pass_ms"] if r else None
        big = render_rows(render, "head", 1024)
        share = f"; {ms / big['raycast_one_pass_ms']:.2f} of the 1024² frame" if ms and big else ""
        add(f"ray caster, CT head, one pass, {size}² (GPU ms of the frame)", f"{fmt(ms, 3)} ms{share}",
            "≤ 0.25 ms at 256²" if size == 256 else "—", None if size != 256 or ms is None else ms <= 0.25)
    ms_b = {b["case"]: median(b["ms"]) for b in (bricked or {}).get("rows", [])}
    cells, worst = [], None
    for name, key in SKIP_PAIRS:
        for mode, suffix in (("two levels", ""), ("one pass", "1p")):
            a, b = ms_b.get(f"{key}{suffix}_skip"), ms_b.get(f"{key}{suffix}_noskip")
            if a and b:
                cells.append(f"{name} {mode} {a / b:.2f}×")
                worst = max(worst or 0.0, a / b)
    add("empty-space skipping against none, 1024² (skip / no skip, median of 5 renders)",
        ", ".join(cells) or "not run", "≤ 1.00× everywhere", None if worst is None else worst <= 1.0)
    for radius in (1, 5, 10):
        fr = [(r["case"], r["sustained_of_copy"]) for r in (t1 or {}).get("rows", [])
              if r["radius"] == radius and r.get("sustained_of_copy")]
        if not fr:
            continue
        add(f"gauss_x, y, z, subtract at R = {radius}, sustained, as a fraction of a plain copy of the "
            "volume in the same run (`importance/copy.comp`)",
            "; ".join(f"{c} " + " / ".join(f"{x * 100:.0f} %" for x in f) for c, f in fr),
            "≥ 85 % each", min(min(f) for _, f in fr) >= 0.85)
    return rows


def table(header, rows):
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(out)


def section(d):
    device_txt = (d / "device.txt").read_text().strip() if (d / "device.txt").exists() else ""
    t1, render, styles = load(d, "table1"), load(d, "render"), load(d, "styles")
    lines, occ, occ512 = load(d, "lines"), load(d, "occlusion"), load(d, "occlusion512")
    styles_ray, scale, bricked = load(d, "styles_raycast"), load(d, "scale"), load(d, "bricked")
    dev = next((t["device"] for t in (t1, render, styles, lines, occ) if t), "unknown device")
    out = [BEGIN, GENERATED + " (issue 30)", "",
           "Written by `benches/device/tables.py` from the JSON that `benches/device/run.sh` brought",
           "back from the lent machine; do not edit by hand. Command, on the lent machine:",
           "`bash benches/device/run.sh` (every bench with `--json`, `VELLUM_VALIDATION=0`).", "",
           "```", device_txt, "```", "", "### Goals", "",
           table(["what", "measured", "goal", ""],
                 goals(dev, t1, render, styles, lines, occ, occ512, styles_ray, load(d, "bricked"),
                       load(d, "vtk")))]
    peer = (load(d, "vtk") or {}).get("peer")
    if peer:
        out += ["", f"### Against VTK (`bench render --repeat 3 --sizes "
                f"{','.join(str(r['size']) for r in peer['rows'])} --orbit-frames {peer['frames']} --peer vtk`; VTK {peer['vtk_renderer']})", "",
                "The CT head, ct-bone, one pass, shading on, two samples per voxel, on the same orbit. "
                "VTK: wall ms of `Render` and `WaitForCompletion`. Ours: GPU ms of the frame's passes, and "
                "wall ms of a ray-caster frame recorded, submitted and waited for alone. VTK's first "
                "frames came back as `vtk_SIZE.png`.", "",
                table(["size", "VTK ms", "slicer GPU ms", "ray caster GPU ms", "ray caster wall ms",
                       "VTK / ray caster wall"],
                      [(f"{r['size']}²", fmt(r["vtk_ms"]), fmt(r["slicer_ms"]), fmt(r["raycast_ms"]),
                        fmt(r["raycast_wall_ms"]), fmt(r["vtk_over_raycast_wall"], 1)) for r in peer["rows"]])]
    if render:
        out += ["", "### Renderers (`bench render --repeat 9`, median GPU ms of a frame)", "",
                table(["data", "size", "slicer one pass", "slicer two levels", "ray caster one pass",
                       "ray caster two levels", "fps (ray, two levels)", "ray / slicer"],
                      [(r["data"], f"{r['size']}²", fmt(r["one_pass_ms"]), fmt(r["two_level_ms"]),
                        fmt(r["raycast_one_pass_ms"]), fmt(r["raycast_two_level_ms"]),
                        fmt(1000 / r["raycast_two_level_ms"], 0) if r["raycast_two_level_ms"] else "—",
                        fmt(r["raycast_ratio"])) for r in render["rows"]]),
                "", "The orbit: two levels, 36 frames turning 10° each, frames in flight; fps over its "
                "wall time, which is bounded by the GPU's ms or the host's, whichever is larger.", "",
                table(["data", "size", "slicer GPU ms", "host ms", "fps", "ray caster GPU ms", "host ms",
                       "fps", "allocs"],
                      [(o["data"], f"{o['size']}²", fmt(o["gpu_ms"]), fmt(o["cpu_record_submit_ms"]),
                        fmt(o["fps"], 0), fmt(o.get("raycast_gpu_ms")), fmt(o.get("raycast_cpu_record_submit_ms")),
                        fmt(o.get("raycast_fps"), 0), o["allocations_after_first_frame"]) for o in render["orbit"]])]
    walk1 = load(d, "render_walk1")
    if render and walk1:
        out += ["", "### The ray caster's walk, batched against one sample at a time (issue 43; "
                "`bench render`, and the same with `VELLUM_WALK_BATCH=0`; GPU ms of the frame)", "",
                table(["data", "size", "one pass: batched", "one at a time", "two levels: batched", "one at a time"],
                      [(r["data"], f"{r['size']}²", fmt(r["raycast_one_pass_ms"], 3), fmt(w["raycast_one_pass_ms"], 3),
                        fmt(r["raycast_two_level_ms"], 3), fmt(w["raycast_two_level_ms"], 3))
                       for r in render["rows"] for w in walk1["rows"]
                       if w["data"] == r["data"] and w["size"] == r["size"]])]
    for st, cmd in ((styles_ray, "--repeat 9 --sizes 1024 --renderer raycast"),
                    (styles, "--repeat 5 --sizes 512,1024")):
        if not st:
            continue
        out += ["", f"### Styles, {st.get('renderer', 'slicer')} (`bench styles {cmd}`, ms)", "",
                table(["data", "size", "style", "frame", "fps", "style passes", "largest passes"],
                      [(r["data"], f"{r['size']}²", f"{r['style']} {r['name']}", fmt(r["frame_ms"]),
                        fmt(r["fps"], 0), fmt(r["post_ms"], 3),
                        ", ".join(f"{n} {ms:.3f}" for n, ms in sorted(r["passes"], key=lambda p: -p[1])[:3]))
                       for r in st["rows"]])]
    if lines:
        out += ["", "### Object-space lines (`bench lines`, GPU ms; CPU reference on the machine's host)", "",
                table(["data", "dims", "kind", "mode", "GPU ms", "segments", "precomputed ms",
                       "Hessian ms", "CPU ms", "CPU segments"],
                      [(r["data"], "×".join(map(str, r["dims"])), r["kind"], r["mode"], fmt(r["gpu_ms"]),
                        r["gpu_segments"], fmt(r["precomputed_ms"]), fmt(r["hessian_ms"]),
                        fmt(r["cpu_ms"], 0), r["cpu_segments"]) for r in lines["rows"]])]
    if t1:
        peak = peak_tbs(dev)
        rows = []
        for r in t1["rows"]:
            for label, ms4 in (("single", r["gauss_ms"] + [r["subtract_ms"]]), ("sustained", r.get("sustained_ms"))):
                if not ms4:
                    continue
                bw = bandwidths(r, ms4)
                rows.append((r["case"], "×".join(map(str, r["dims"])), r["radius"], label,
                             *(f"{ms:.3f} ({b:.2f})" for ms, b in zip(ms4, bw)),
                             fmt(min(bw) / peak * 100, 0) if peak else "—", fmt(r["paper_total_ms"], 1)))
        out += ["", f"### Importance passes (`bench table1 --no-scipy --repeat {t1['repeat']} --sustained 40`; "
                f"ms, and TB/s read + written; peak {peak} TB/s by datasheet)", "",
                "Single: the median pass of the runs, each an upload, the passes and a readback. "
                "Sustained: the median of 40 rounds of the passes recorded back to back on the volume "
                "uploaded once, in the last of three submissions.", "",
                table(["case", "dims", "R", "timing", "gauss_x", "gauss_y", "gauss_z", "subtract",
                       "slowest % of peak", "paper total ms"], rows)]
        copies = [r for r in t1["rows"] if r.get("sustained_of_copy")]
        if copies:
            out += ["", "Against a plain copy of the same volume in the same run (sustained; "
                    "`importance/copy.comp`, a compute pass over the passes' images; the subtract "
                    "against 1.5 copies):", "",
                    table(["case", "R", "copy ms (TB/s)", "gauss_x", "gauss_y", "gauss_z", "subtract"],
                          [(r["case"], r["radius"],
                            f"{r['sustained_copy_ms']:.3f} ({bandwidths(r, [r['sustained_copy_ms']])[0]:.2f})",
                            *(f"{x * 100:.0f} %" for x in r["sustained_of_copy"])) for r in copies])]
    sweep = sorted(d.glob("sweep_*.json"))
    if sweep:
        rows = []
        for f in sweep:
            label = f.stem.removeprefix("sweep_").replace("_", ",").replace("tile,", "tile ").replace("x,", "x tile ")
            for r in json.loads(f.read_text())["rows"]:
                ms4 = r.get("sustained_ms")
                if not ms4:
                    continue
                bw = bandwidths(r, ms4)
                rows.append((label, r["case"], r["radius"],
                             *(f"{ms:.3f} ({b:.2f})" for ms, b in zip(ms4[:3], bw))))
        out += ["", "### Gaussian kernels (`VELLUM_GAUSS_KERNEL=segments|tiled`, `VELLUM_GAUSS_TILE=TX,DEPTH,LANES,LENGTH` "
                "(y and z passes), `VELLUM_GAUSS_TILE_X=N`; `bench table1 --sustained 40 --cases ...`; ms, and TB/s read + written)", "",
                table(["kernel", "case", "R", "gauss_x", "gauss_y", "gauss_z"], rows)]
    if scale or bricked:
        rows = [(b["case"], " ".join(f"{x:.3f}" for x in b["ms"]), fmt(median(b["ms"]), 3))
                for b in (bricked or {}).get("rows", [])]
        out += ["", "### Bricked ray caster (Shepp–Logan 256³ store, 1024², two levels; `render` five times each, "
                "GPU ms of pass `raycast`)", "", table(["case", "ms", "median"], rows)]
        for r in (scale or {}).get("rows", []):
            b = r.get("bricked", {})
            out += ["", f"`bench scale` {r['n']}³: store written at {fmt(r['write'].get('mib_per_s'), 0)} MiB/s; "
                    f"bricked frame {fmt(b.get('passes', {}).get('raycast'), 3)} ms of ray casting, "
                    f"in core {fmt(r.get('in_core', {}).get('passes', {}).get('raycast'), 3)} ms; "
                    f"{fmt(b.get('bricks', {}).get('total_ms'), 0)} ms to a complete frame."]
    for label, o in (("bonsai 256³", occ), ("Shepp–Logan 512³", occ512)):
        if not o:
            continue
        rows = []
        for r in o["rows"]:
            for c in r["cells"]:
                rows.append((r["radius"], "×".join(map(str, r["pad"])), c["method"], fmt(c["ms"], 1),
                             fmt(c["estimate_ms"], 1), fmt(c["memory_bytes"] / 2**20, 0),
                             ", ".join(f"{n} {ms:.2f}" for n, ms in sorted(c["passes"], key=lambda p: -p[1])[:4])))
        out += ["", f"### Ambient occlusion, {label} (`bench occlusion`)", "",
                table(["R", "padded", "method", "ms", "model ms", "MiB", "largest passes (ms)"], rows)]
    out.append(END)
    return "\n".join(out) + "\n"


def main():
    d = pathlib.Path(sys.argv[1])
    if d.is_file():  # results.tar as run.sh leaves it under $OUT
        tmp = pathlib.Path(tempfile.mkdtemp())
        with tarfile.open(d) as tar:
            tar.extractall(tmp, filter="data")
        d = tmp
    md = pathlib.Path(sys.argv[2] if len(sys.argv) > 2 else "BENCHMARKS.md")
    text, new = md.read_text(), section(d)
    if BEGIN in text and END in text:
        head, rest = text.split(BEGIN, 1)
        inside, tail = rest.split(END, 1)
        # Sections written by hand between the markers (a `## ` heading other than the generated
        # one) are kept, in their order, before the new section: only the generated section is
        # replaced (a misplaced marker once took the MPI and first-five-minutes sections with it).
        kept = [b for b in re.split(r"(?m)^(?=## )", inside)
                if b.startswith("## ") and not b.startswith(GENERATED)]
        head = head + "".join(b.rstrip("\n") + "\n\n" for b in kept)
        text = head + new + "\n" + tail.lstrip("\n")
    else:
        text = text.rstrip("\n") + "\n\n" + new
    md.write_text(text)
    print(f"wrote the GPU tables into {md} from {d}")


if __name__ == "__main__":
    main()
