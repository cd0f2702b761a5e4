#!/usr/bin/env bash
# Runs on the lent GPU machine (through the device tool, with .device carried): the experiments
# behind issue 30's changes, each one variant against another in the same call.
#   - the Gaussian kernels (segments, tiles), sustained, on Table 1's CT head;
#   - where the bricked ray caster's time goes: in core with and without empty-space skipping,
#     and through the brick cache, on a 256³ phantom store at 1024².
set -uo pipefail
cd "$(dirname "$0")/../.."
: "${OUT:?OUT must name the folder whose files come back}"
B=.device
for f in "$B"/debs/*.deb; do dpkg -x "$f" /; done
ldconfig
export VELLUM_DATA="$B/data" VELLUM_VALIDATION=0
V="$B/vellum"
R=$(mktemp -d)
pack() { tar -C "$R" -cf "$OUT/profile.tar" .; }

gauss() {
    local name=$1
    timeout 120 "$V" bench table1 --no-scipy --repeat 3 --sustained 40 \
        --cases ct-head:1,ct-head:5,ct-head:10,salmon:5 --json >"$R/gauss_$name.json" 2>"$R/gauss_$name.log"
    echo "gauss $name: rc $?"
    python3 - "$R/gauss_$name.json" <<'PY'
import json, sys
for r in json.load(open(sys.argv[1]))["rows"]:
    n = (r["dims"][0] + 3) // 4 * 16 * r["dims"][1] * r["dims"][2]
    s = r["sustained_ms"]
    bw = [2 * n / (m * 1e-3) / 1e12 for m in s[:3]] + [3 * n / (s[3] * 1e-3) / 1e12]
    print(f'  {r["case"]} R={r["radius"]}: ' + ", ".join(f"{m:.3f} ms {b:.2f} TB/s" for m, b in zip(s, bw)))
PY
    pack
}
[ -n "${NO_SEGMENTS:-}" ] || VELLUM_GAUSS_KERNEL=segments gauss segments
# Tiles of the y and z passes: TX,DEPTH,LANES,LENGTH.
for t in ${TILES:-32,1,8,64 16,1,16,64 8,1,32,64 16,2,8,64 16,2,16,64 32,1,16,64 8,4,8,64 16,4,4,32}; do
    VELLUM_GAUSS_KERNEL=tiled VELLUM_GAUSS_TILE=$t gauss "tile_${t//,/_}"
done
for x in ${TILES_X:-32 128 256}; do
    VELLUM_GAUSS_KERNEL=tiled VELLUM_GAUSS_TILE_X=$x gauss "tile_x_$x"
done

[ -z "${NO_RENDER:-}" ] || exit 0
"$V" convert phantom:shepp-logan:256 /tmp/s.ome.zarr >/dev/null 2>&1
mib=$(python3 -c "print(256**3*10/2**20)")
A="/tmp/s.ome.zarr --iso 0.9 --tf grey --camera 30,20,2.5 --size 1024x1024 --renderer raycast --out /tmp/x.png"
case_() {
    local name=$1; shift
    for i in 1 2 3 4 5; do
        timeout 60 "$V" render $A "$@" 2>&1 | grep -E "^\s+raycast " | awk '{print $2}'
    done >"$R/$name.txt"
    echo "$name: $(tr '\n' ' ' <"$R/$name.txt")"
    pack
}
case_ core_skip --gpu-budget "$(python3 -c "print($mib*1.5)")"
case_ core_noskip --gpu-budget "$(python3 -c "print($mib*1.5)")" --no-skip-empty
VELLUM_BRICK_REUSE=0 case_ bricked_lookup --gpu-budget "$(python3 -c "print($mib*0.99)")" --lod finest
VELLUM_BRICK_REUSE=1 case_ bricked_reuse --gpu-budget "$(python3 -c "print($mib*0.99)")" --lod finest
# Empty-space skipping in core on the bench render's volumes, two levels at 1024².
if [ -n "${SKIP_CASES:-}" ]; then
    D=$B/data/volumes
    A="$D/cthead_stanford/cthead_stanford.nhdr --iso 1300 --tf ct-skin-bone --size 1024x1024 --renderer raycast --out /tmp/x.png"
    case_ head_skip
    case_ head_noskip --no-skip-empty
    A="$D/engine/engine.nhdr --iso 180 --tf grey --size 1024x1024 --renderer raycast --out /tmp/x.png"
    case_ engine_skip
    case_ engine_noskip --no-skip-empty
fi
