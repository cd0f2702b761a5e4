#!/usr/bin/env python3
"""The renderer users pick instead of vellum: VTK's vtkGPUVolumeRayCastMapper (ParaView's and
3D Slicer's), off screen through EGL; on a machine without a GPU that is Mesa's llvmpipe, the same
software rasteriser as lavapipe.

Usage: vtk_peer.py VOLUME.raw X Y Z SX SY SZ TF.json SIZES FRAMES OUTDIR
  VOLUME.raw  little-endian uint16, x fastest (written by `vellum bench render --peer vtk`)
  TF.json     vellum's transfer function: points with x in [0, 1] of the data range and rgba,
              alpha as opacity per voxel of distance (the smallest spacing)
  SIZES       comma-separated image sizes, e.g. 256,512,1024
  FRAMES      frames of the orbit (10 degrees apart) after one warm-up frame
Renders with the same settings as vellum's one-pass render: linear interpolation, sample distance
half the smallest voxel, shading on with ambient 0.25, diffuse 0.75, specular 0.35, power 24 and a
headlight, a 50 degree perspective camera at elevation 20 and 2.5 bounding radii. Prints
{"renderer": ..., "sizes": [{"size": N, "median_ms": ..., "frames_ms": [...]}]} and writes the
first frame of each size as OUTDIR/vtk_SIZE.png.
"""
import json
import math
import statistics
import sys
import time

import numpy as np

# Only the modules named here, so that the cut-down VTK of benches/device/slim_vtk.py (which lists
# the same modules in PEER) serves the lent GPU machine. The two OpenGL2 imports register the
# OpenGL implementations of the render window and of the volume mapper.
import vtkmodules.vtkRenderingOpenGL2  # noqa: F401
import vtkmodules.vtkRenderingVolumeOpenGL2  # noqa: F401
from vtkmodules.util import numpy_support
from vtkmodules.vtkCommonCore import VTK_UNSIGNED_SHORT
from vtkmodules.vtkCommonDataModel import vtkImageData, vtkPiecewiseFunction
from vtkmodules.vtkIOImage import vtkPNGWriter
from vtkmodules.vtkRenderingCore import (
    vtkColorTransferFunction,
    vtkRenderer,
    vtkRenderWindow,
    vtkVolume,
    vtkVolumeProperty,
    vtkWindowToImageFilter,
)
from vtkmodules.vtkRenderingVolume import vtkGPUVolumeRayCastMapper


def main():
    raw, x, y, z, sx, sy, sz, tf_path, sizes, frames, outdir = sys.argv[1:12]
    dims = (int(x), int(y), int(z))
    spacing = (float(sx), float(sy), float(sz))
    data = np.fromfile(raw, dtype="<u2")
    lo, hi = float(data.min()), float(data.max())
    image = vtkImageData()
    image.SetDimensions(*dims)
    image.SetSpacing(*spacing)
    array = numpy_support.numpy_to_vtk(data, deep=True, array_type=VTK_UNSIGNED_SHORT)
    image.GetPointData().SetScalars(array)

    with open(tf_path) as f:
        tf = json.load(f)
    color = vtkColorTransferFunction()
    opacity = vtkPiecewiseFunction()
    for p in tf["points"]:
        s = lo + p["x"] * (hi - lo)
        r, g, b, a = p["rgba"]
        color.AddRGBPoint(s, r, g, b)
        opacity.AddPoint(s, a)

    voxel = min(spacing)
    prop = vtkVolumeProperty()
    prop.SetColor(color)
    prop.SetScalarOpacity(opacity)
    prop.SetScalarOpacityUnitDistance(voxel)
    prop.SetInterpolationTypeToLinear()
    prop.ShadeOn()
    prop.SetAmbient(0.25)
    prop.SetDiffuse(0.75)
    prop.SetSpecular(0.35)
    prop.SetSpecularPower(24.0)

    mapper = vtkGPUVolumeRayCastMapper()
    mapper.SetInputData(image)
    mapper.SetAutoAdjustSampleDistances(0)
    mapper.SetSampleDistance(0.5 * voxel)
    volume = vtkVolume()
    volume.SetMapper(mapper)
    volume.SetProperty(prop)

    renderer = vtkRenderer()
    renderer.AddVolume(volume)
    renderer.SetBackground(0, 0, 0)
    window = vtkRenderWindow()
    window.SetOffScreenRendering(1)
    window.AddRenderer(renderer)

    bounds = volume.GetBounds()
    centre = [(bounds[0] + bounds[1]) / 2, (bounds[2] + bounds[3]) / 2, (bounds[4] + bounds[5]) / 2]
    radius = 0.5 * math.sqrt(sum((bounds[2 * i + 1] - bounds[2 * i]) ** 2 for i in range(3)))
    camera = renderer.GetActiveCamera()
    camera.SetViewAngle(50.0)

    def place(azimuth):
        el, az = math.radians(20.0), math.radians(azimuth)
        d = 2.5 * radius
        camera.SetFocalPoint(*centre)
        camera.SetPosition(
            centre[0] + d * math.cos(el) * math.sin(az),
            centre[1] - d * math.cos(el) * math.cos(az),
            centre[2] + d * math.sin(el),
        )
        camera.SetViewUp(0, 0, 1)
        renderer.ResetCameraClippingRange()

    out = {"sizes": []}
    for size in [int(s) for s in sizes.split(",")]:
        window.SetSize(size, size)
        place(30.0)
        window.Render()
        window.WaitForCompletion()
        grab = vtkWindowToImageFilter()
        grab.SetInput(window)
        grab.ReadFrontBufferOff()
        grab.Update()
        writer = vtkPNGWriter()
        writer.SetFileName(f"{outdir}/vtk_{size}.png")
        writer.SetInputConnection(grab.GetOutputPort())
        writer.Write()
        times = []
        for k in range(int(frames)):
            place(30.0 + 10.0 * (k + 1))
            t0 = time.perf_counter()
            window.Render()
            window.WaitForCompletion()
            times.append((time.perf_counter() - t0) * 1e3)
        out["sizes"].append({"size": size, "median_ms": statistics.median(times), "frames_ms": times})
    out["renderer"] = window.ReportCapabilities().split("OpenGL renderer string:")[-1].split("\n")[0].strip()
    print(json.dumps(out))


if __name__ == "__main__":
    main()
