#!/usr/bin/env python3
"""Cuts VTK's wheel down to what benches/vtk_peer.py imports, so that it travels to the lent GPU
machine inside the device tool's 64 MiB: the wrapper modules the peer names (the PEER list below,
which must match its imports), the shared libraries they need (the closure of their ELF NEEDED
entries inside the wheel) and the wrappers of those libraries, VTK's pure-Python package files, each library stripped, in one .tar.xz
with the x86 branch filter.

The wheel is 140 MB and unpacks to 560 MB; the cut is smaller than a quarter of that.

Usage: slim_vtk.py WHEEL OUT.tar.xz
"""
import lzma
import os
import re
import subprocess
import sys
import tarfile
import tempfile
import zipfile

# The wrapper modules benches/vtk_peer.py imports (keep in step with its imports).
PEER = [
    "vtkCommonCore",
    "vtkCommonDataModel",
    "vtkCommonExecutionModel",
    "vtkIOImage",
    "vtkRenderingCore",
    "vtkRenderingOpenGL2",
    "vtkRenderingVolume",
    "vtkRenderingVolumeOpenGL2",
]


def needed(path):
    """The NEEDED entries of one shared library."""
    out = subprocess.run(["readelf", "-d", path], capture_output=True, text=True, check=True)
    return re.findall(r"\(NEEDED\).*\[(.*)\]", out.stdout)


def closure(folder, roots):
    """The files inside `folder` that `roots` need, transitively, with the roots."""
    seen, stack = set(), list(roots)
    while stack:
        name = stack.pop()
        if name in seen:
            continue
        seen.add(name)
        stack += [n for n in needed(os.path.join(folder, name)) if os.path.exists(os.path.join(folder, n))]
    return seen


def main():
    wheel, out = sys.argv[1:3]
    with tempfile.TemporaryDirectory() as tmp, zipfile.ZipFile(wheel) as z:
        names = z.namelist()
        tag = next(n for n in names if n.startswith("vtkmodules/vtkCommonCore.") and n.endswith(".so"))
        suffix = tag[len("vtkmodules/vtkCommonCore") :]
        roots = [m + suffix for m in PEER]
        missing = [r for r in roots if "vtkmodules/" + r not in names]
        if missing:
            sys.exit(f"{wheel} has no {', '.join(missing)}")
        libs = [n for n in names if n.startswith("vtkmodules/") and n.count("/") == 1 and ".so" in n]
        z.extractall(tmp, libs)
        # A wrapper module imports the wrappers of the modules it builds on, so each library kept
        # brings its own wrapper, which may need more libraries: grow both until they stop.
        folder, keep = os.path.join(tmp, "vtkmodules"), set()
        while True:
            keep = closure(folder, roots)
            wrappers = {w for w in (k[len("lib") : -len(".so")] + suffix for k in keep if k.startswith("libvtk")) if os.path.exists(os.path.join(folder, w))}
            if wrappers <= set(roots):
                break
            roots = sorted(set(roots) | wrappers)
        # Pure Python: the package's own files and its util folder (numpy_support).
        python = [
            n
            for n in names
            if n.endswith(".py") and (n.count("/") == 1 or n.startswith("vtkmodules/util/")) and n.startswith("vtkmodules/")
        ]
        z.extractall(tmp, python)
        files = sorted(["vtkmodules/" + k for k in keep]) + sorted(python)
        subprocess.run(["strip", "--strip-unneeded"] + [os.path.join(tmp, f) for f in files if ".so" in f], check=True)
        filters = [
            {"id": lzma.FILTER_X86},
            {"id": lzma.FILTER_LZMA2, "preset": 9 | lzma.PRESET_EXTREME, "dict_size": 192 << 20},
        ]
        part = out + ".part"
        with lzma.open(part, "wb", format=lzma.FORMAT_XZ, filters=filters) as xz, tarfile.open(fileobj=xz, mode="w") as tar:
            for f in files:
                tar.add(os.path.join(tmp, f), arcname=f)
        os.replace(part, out)
        size = sum(os.path.getsize(os.path.join(tmp, f)) for f in files)
        print(f"{out}: {len(files)} files, {size / 2**20:.0f} MiB unpacked, {os.path.getsize(out) / 2**20:.1f} MiB packed")


if __name__ == "__main__":
    main()
