#!/usr/bin/env python3
"""Writes BENCHMARKS.md's GPU tables from the JSON that benches/device/run.sh brought back.

    python3 benches/device/tables.py DIR [BENCHMARKS.md]

DIR (or the results.tar run.sh leaves) holds device.txt and one JSON file per bench (table1, render, styles, lines, occlusion,
occlusion512); a missing one leaves its rows saying so. The text between the two marker lines
`<!-- bench-device:begin -->` and `<!-- bench-device:end -->` is replaced (appended when absent);
nothing else in the file is touched. Standard library only.
"""

import json
import pathlib
import sys
import tarfile
import tempfile

BEGIN, END = "<!-- bench-device:begin -->", "<!-- bench-device:end -->"

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


def goals(dev, t1, render, styles, lines, occ, occ512, styles_ray=None, sweep88=None):
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
    # The Table 1 run, and the sweep's run of the default segment lengths (8, 8): the same passes
    # in two processes minutes apart, which have differed by up to 2× (see the section's note).
    for label, table in (("table1", t1), ("sweep 8, 8", sweep88)):
        for r in [r for r in (table or {}).get("rows", []) if r["case"] == "ct-head"]:
            n = r["dims"][0] * r["dims"][1] * r["dims"][2] * 4
            bw = [2 * n / (ms * 1e-3) / 1e12 for ms in r["gauss_ms"]] + [3 * n / (r["subtract_ms"] * 1e-3) / 1e12]
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
    add("bricked ray caster against in-core", "not built yet (issue 26)", "≤ 1.3×", None)
    add("VTK's GPU ray caster on the same GPU", "not run (the vtk wheel exceeds the 64 MiB "
        "the device tool carries)", "ours ≤ 0.25×", None)
    return rows


def table(header, rows):
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(out)


def section(d):
    device_txt = (d / "device.txt").read_text().strip() if (d / "device.txt").exists() else ""
    t1, render, styles = load(d, "table1"), load(d, "render"), load(d, "styles")
    lines, occ, occ512 = load(d, "lines"), load(d, "occlusion"), load(d, "occlusion512")
    styles_ray = load(d, "styles_raycast")
    dev = next((t["device"] for t in (t1, render, styles, lines, occ) if t), "unknown device")
    out = [BEGIN, "## On a GPU: every bench through `make bench-device` (issue 30)", "",
           "Written by `benches/device/tables.py` from the JSON that `benches/device/run.sh` brought",
           "back from the lent machine; do not edit by hand. Command, on the lent machine:",
           "`bash benches/device/run.sh` (every bench with `--json`, `VELLUM_VALIDATION=0`).", "",
           "```", device_txt, "```", "", "### Goals", "",
           table(["what", "measured", "goal", ""], goals(dev, t1, render, styles, lines, occ, occ512, styles_ray, load(d, "gauss_8_8")))]
    if render:
        out += ["", "### Renderers (`bench render --repeat 9`, median GPU ms of a frame)", "",
                table(["data", "size", "slicer one pass", "slicer two levels", "ray caster one pass",
                       "ray caster two levels", "fps (ray, two levels)", "ray / slicer"],
                      [(r["data"], f"{r['size']}²", fmt(r["one_pass_ms"]), fmt(r["two_level_ms"]),
                        fmt(r["raycast_one_pass_ms"]), fmt(r["raycast_two_level_ms"]),
                        fmt(1000 / r["raycast_two_level_ms"], 0) if r["raycast_two_level_ms"] else "—",
                        fmt(r["raycast_ratio"])) for r in render["rows"]]),
                "", table(["data", "size", "orbit GPU ms", "host ms", "orbit fps", "allocs"],
                          [(o["data"], f"{o['size']}²", fmt(o["gpu_ms"]), fmt(o["cpu_record_submit_ms"]),
                            fmt(o["fps"], 0), o["allocations_after_first_frame"]) for o in render["orbit"]])]
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
            n = r["dims"][0] * r["dims"][1] * r["dims"][2] * 4
            bw = [2 * n / (ms * 1e-3) / 1e12 for ms in r["gauss_ms"]] + [3 * n / (r["subtract_ms"] * 1e-3) / 1e12]
            rows.append((r["case"], "×".join(map(str, r["dims"])), r["radius"],
                         *(f"{ms:.3f} ({b:.2f})" for ms, b in zip(r["gauss_ms"] + [r["subtract_ms"]], bw)),
                         fmt(min(bw) / peak * 100, 0) if peak else "—", fmt(r["paper_total_ms"], 1)))
        out += ["", f"### Importance passes (`bench table1 --no-scipy --repeat {t1['repeat']}`; ms, and TB/s read + written; "
                f"peak {peak} TB/s by datasheet)", "",
                table(["case", "dims", "R", "gauss_x", "gauss_y", "gauss_z", "subtract", "slowest % of peak",
                       "paper total ms"], rows)]
    sweep = sorted(d.glob("gauss_*.json"))
    if sweep:
        rows = []
        for f in sweep:
            yz, x = f.stem.split("_")[1:3]
            for r in json.loads(f.read_text())["rows"]:
                n = r["dims"][0] * r["dims"][1] * r["dims"][2] * 4
                bw = [2 * n / (ms * 1e-3) / 1e12 for ms in r["gauss_ms"]]
                rows.append((f"{yz}, {x}", r["case"], r["radius"],
                             *(f"{ms:.3f} ({b:.2f})" for ms, b in zip(r["gauss_ms"], bw))))
        out += ["", "### Gaussian segment lengths (`VELLUM_GAUSS_SEGMENTS=YZ,X bench table1 --cases ...`; "
                "ms, and TB/s read + written)", "",
                table(["segments y/z, x", "case", "R", "gauss_x", "gauss_y", "gauss_z"], rows)]
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
        text = head + new + "\n" + rest.split(END, 1)[1].lstrip("\n")
    else:
        text = text.rstrip("\n") + "\n\n" + new
    md.write_text(text)
    print(f"wrote the GPU tables into {md} from {d}")


if __name__ == "__main__":
    main()
