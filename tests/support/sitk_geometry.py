"""Prints the geometry SimpleITK (ITK's own readers) reads for each path, as JSON:
{path: {"size", "spacing", "origin", "direction"}}. A folder is read as a DICOM series.
Used by tests/geometry.rs as the independent reference for origin and direction."""
import json
import os
import sys

import SimpleITK as sitk


def read(path):
    if os.path.isdir(path):
        reader = sitk.ImageSeriesReader()
        reader.SetFileNames(sitk.ImageSeriesReader.GetGDCMSeriesFileNames(path))
        return reader.Execute()
    return sitk.ReadImage(path)


out = {}
for path in sys.argv[1:]:
    image = read(path)
    out[path] = {
        "size": list(image.GetSize()),
        "spacing": list(image.GetSpacing()),
        "origin": list(image.GetOrigin()),
        "direction": list(image.GetDirection()),
    }
print(json.dumps(out))
