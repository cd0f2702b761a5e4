#!/usr/bin/env bash
# Runs on the lent GPU machine (through the device tool), in the root of the working tree's copy,
# with the bundle that `make bench-device` packed into .device/ carried along. Runs every bench
# with --json and leaves one JSON file per bench, the logs and a device summary under $OUT.
#
#   BENCHES="render styles" bash benches/device/run.sh    # a subset (default: all)
#
# Each bench gets its own time limit, so one slow bench cannot take the others' results with it.
set -uo pipefail
cd "$(dirname "$0")/../.."
: "${OUT:?OUT must name the folder whose files come back}"
B=.device
[ -x "$B/vellum" ] || { echo "no $B/vellum: run make bench-device first and carry .device"; exit 2; }

# The Vulkan loader, the GL dispatch libraries NVIDIA's ICD (libGLX_nvidia) needs to hand out
# vkCreateInstance, and the Khronos layer for the validation run, from Debian's packages.
for f in "$B"/debs/*.deb; do dpkg -x "$f" /; done
ldconfig
export VELLUM_DATA="$B/data" VELLUM_VALIDATION=0 RUST_LOG=warn
if ! "$B/vellum" devices >/dev/null 2>&1; then
    export VK_DRIVER_FILES=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
fi
V="$B/vellum"
# The device tool brings back at most 8 files: everything goes into one tar, results.tar.
R=$(mktemp -d)

{
    echo "date: $(date -u +%Y-%m-%dT%H:%MZ)"
    nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.max.sm,clocks.max.mem --format=csv,noheader
    "$V" devices
    nproc
} >"$R/device.txt" 2>&1
cat "$R/device.txt"

# name, limit in seconds, then the bench's arguments.
run() {
    local name=$1 limit=$2
    shift 2
    case " ${BENCHES:-all} " in *" all "* | *" $name "* | *" ${name%%_*} "*) ;; *) return ;; esac
    local t0=$SECONDS
    timeout "$limit" "$V" bench "$@" --json >"$R/$name.json" 2>"$R/$name.log"
    local rc=$?
    echo "$name: rc $rc, $((SECONDS - t0)) s"
    [ $rc -eq 0 ] || { tail -5 "$R/$name.log"; rm -f "$R/$name.json"; }
}

# table1 after the renderers: its sub-millisecond passes read low on a GPU whose clocks have
# not yet ramped up (seen as half the bandwidth when it ran first).
run render 150 render --repeat 9
run styles 120 styles --repeat 5 --sizes 512,1024
run table1 100 table1 --no-scipy --repeat 9
run styles_raycast 60 styles --repeat 9 --sizes 1024 --renderer raycast
run lines 80 lines
run occlusion 150 occlusion --methods runs,fft-gpu --radii 4,8,16,32,64,100 --max-seconds 20
run occlusion512 80 occlusion phantom:shepp-logan:512 --methods fft-gpu --radii 64

# The Gaussian passes' segment lengths (texels per invocation along y/z, and along x), swept on
# the Table 1 cases: what Segments::choose takes on a GPU comes from here.
for s in 4,4 8,4 16,4 32,4 8,8 16,8 4,8 16,2; do
    VELLUM_GAUSS_SEGMENTS=$s run "gauss_${s/,/_}" 60 table1 --no-scipy --repeat 5 \
        --cases ct-head:1,ct-head:5,ct-head:10,salmon:5
done

# Synchronization validation on a real asynchronous GPU: one two-level frame and one styled frame
# with lines, through the Khronos layer (packed when the host had it).
case " ${BENCHES:-all} " in *" all "* | *" validation "*)
    if ls /usr/share/vulkan/explicit_layer.d/VkLayer_khronos_validation.json >/dev/null 2>&1; then
        VELLUM_VALIDATION=1 VELLUM_SYNC_VALIDATION=1 timeout 120 "$V" render \
            "$B/data/volumes/cthead_stanford/cthead_stanford.nhdr" --iso 1300 --tf ct-skin-bone \
            --renderer raycast --style 11 --size 512x512 --out /tmp/v.png >"$R/validation.log" 2>&1
        echo "validation: rc $? ($(grep -ci 'validation' "$R/validation.log") lines naming validation)"
    fi
    ;;
esac
tar -C "$R" -cf "$OUT/results.tar" . && tar -tvf "$OUT/results.tar"
