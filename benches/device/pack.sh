#!/usr/bin/env bash
# Packs what the lent GPU machine needs into .device/ (ignored by git, carried by the device
# tool): the release binary built here, the Vulkan loader and the Khronos validation layer as
# Debian packages, and the volumes the benches read. Run by `make bench-device`.
set -euo pipefail
cd "$(dirname "$0")/../.."
B=.device
DATA=${VELLUM_DATA:-../shared/data}
rm -rf "$B" && mkdir -p "$B/debs" "$B/data/volumes"
cp target/release/vellum "$B/vellum"
strip --strip-all "$B/vellum"
(cd "$B/debs" && apt-get download libvulkan1 libglvnd0 libglx0 libegl1 vulkan-validationlayers >/dev/null 2>&1)
# cthead_stanford and engine: bench render, styles and lines; bonsai: bench occlusion;
# ct_chest_lidc2 and boston_teapot: bench table1's CT body and salmon.
for v in cthead_stanford engine bonsai ct_chest_lidc2 boston_teapot; do
    [ -d "$DATA/volumes/$v" ] || { echo "$DATA/volumes/$v is missing"; exit 1; }
    cp -r "$DATA/volumes/$v" "$B/data/volumes/"
done
du -sh "$B"
