#!/usr/bin/env bash
# Packs what the lent GPU machine needs into .device/ (ignored by git, carried by the device
# tool): the release binary built here, the Vulkan loader, the GL and EGL dispatch libraries and
# the Khronos validation layer as Debian packages, the volumes the benches read, and a cut-down
# VTK for the GPU peer (benches/device/slim_vtk.py). Run by `make bench-device`.
#
#   VTK=0 make bench-device     # without VTK (29 MiB less to carry)
#
# The device tool carries at most 64 MiB a call, the working tree included, so the binary and
# VTK travel xz-compressed, a volume the tree already holds is not packed twice, and the total
# is checked at the end.
set -euo pipefail
cd "$(dirname "$0")/../.."
B=.device
DATA=${VELLUM_DATA:-../shared/data}
CACHE=target/device-cache
# The lent machine's python3 (KINDS.md): VTK's wheel must match it.
VTK_VERSION=9.7.2 VTK_PYTHON=${VTK_PYTHON:-3.12}
rm -rf "$B" && mkdir -p "$B/debs" "$B/data/volumes" "$CACHE"

strip --strip-all -o "$CACHE/vellum" target/release/vellum
xz --x86 --lzma2=preset=9 -T0 -c "$CACHE/vellum" >"$B/vellum.xz"

(cd "$B/debs" && apt-get download libvulkan1 libglvnd0 libglx0 libegl1 libopengl0 libgl1 \
    vulkan-validationlayers >/dev/null 2>&1)

# cthead_stanford and engine: bench render, styles and lines; bonsai: bench occlusion;
# ct_chest_lidc2 and boston_teapot: bench table1's CT body and salmon. A data file the working
# tree holds byte for byte (the chest is data/ct_chest) is copied there by run.sh instead.
: >"$B/data/from_tree.txt"
for v in cthead_stanford engine bonsai ct_chest_lidc2 boston_teapot; do
    [ -d "$DATA/volumes/$v" ] || { echo "$DATA/volumes/$v is missing"; exit 1; }
    mkdir -p "$B/data/volumes/$v"
    for f in "$DATA/volumes/$v"/*; do
        twin=$(git ls-files data | while read -r t; do cmp -s "$f" "$t" && { echo "$t"; break; }; done || true)
        if [ -n "$twin" ]; then
            echo "$B/data/volumes/$v/$(basename "$f") $twin" >>"$B/data/from_tree.txt"
        else
            cp "$f" "$B/data/volumes/$v/"
        fi
    done
done

# The frog tissue's label volume (issue 42's segments in core and through the brick cache).
mkdir -p "$B/data/formats/metaimage"
cp "$DATA/formats/metaimage/frogtissue.mhd" "$DATA/formats/metaimage/frogtissue.zraw" \
    "$B/data/formats/metaimage/"

if [ "${VTK:-1}" = 1 ]; then
    whl=$(ls "$CACHE"/vtk-"$VTK_VERSION"-cp"${VTK_PYTHON/./}"-*.whl 2>/dev/null | head -1 || true)
    if [ -z "$whl" ]; then
        python3 -m pip download --quiet --no-deps --only-binary=:all: --implementation cp \
            --python-version "$VTK_PYTHON" --platform manylinux_2_17_x86_64 \
            --platform manylinux2014_x86_64 -d "$CACHE" "vtk==$VTK_VERSION"
        whl=$(ls "$CACHE"/vtk-"$VTK_VERSION"-cp"${VTK_PYTHON/./}"-*.whl | head -1)
    fi
    slim="$CACHE/$(basename "$whl" .whl).slim.tar.xz"
    # Cut again when the cut or the peer's imports changed (two minutes).
    if [ ! -f "$slim" ] || [ benches/device/slim_vtk.py -nt "$slim" ] || [ benches/vtk_peer.py -nt "$slim" ]; then
        python3 benches/device/slim_vtk.py "$whl" "$slim"
    fi
    cp "$slim" "$B/vtk.tar.xz"
fi

# What one call carries: the working tree (tracked files and untracked ones git does not ignore)
# and .device.
# (A tracked file deleted from the working tree does not travel: stat skips it.)
tree=$( (git ls-files -z; git ls-files -z -o --exclude-standard) | { xargs -0 stat -c %s 2>/dev/null || true; } |
    awk '{s += $1} END {print s}')
bundle=$(du -sb "$B" | cut -f1)
total=$((tree + bundle))
awk -v b="$bundle" -v t="$total" -v d="$B" 'BEGIN {printf "%s: %.1f MiB, with the working tree %.1f MiB of the 64 MiB a device call carries\n", d, b / 1048576, t / 1048576}'
if [ "$total" -gt $((63 * 1048576)) ]; then
    echo "that is too close to the device tool's 64 MiB: pack again with VTK=0 and run the VTK peer in a call of its own"
    exit 1
fi
