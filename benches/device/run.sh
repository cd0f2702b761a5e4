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
[ -f "$B/vellum.xz" ] || { echo "no $B/vellum.xz: run make bench-device first and carry .device"; exit 2; }
# Python's lzma, not xz(1), which the machine may lack; pack.sh compressed with the x86 filter.
unxz_to() { python3 -c 'import lzma, shutil, sys; shutil.copyfileobj(lzma.open(sys.argv[1]), open(sys.argv[2], "wb"))' "$1" "$2"; }
V=/tmp/vellum
unxz_to "$B/vellum.xz" "$V" && chmod +x "$V"
# Data files pack.sh left out because the working tree holds them byte for byte.
while read -r to from; do mkdir -p "$(dirname "$to")" && cp "$from" "$to"; done <"$B/data/from_tree.txt"

# The Vulkan loader, the GL dispatch libraries NVIDIA's ICD (libGLX_nvidia) needs to hand out
# vkCreateInstance and VTK needs for EGL, and the Khronos layer for the validation run, from
# Debian's packages.
# SKIP_DEBS=1 leaves them out, for a rehearsal on the development machine, which has them.
if [ "${SKIP_DEBS:-0}" != 1 ]; then
    for f in "$B"/debs/*.deb; do dpkg -x "$f" /; done
    ldconfig
fi
export VELLUM_DATA="$B/data" VELLUM_VALIDATION=0 RUST_LOG=warn
if ! "$V" devices >/dev/null 2>&1; then
    export VK_DRIVER_FILES=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
fi
N=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
if [ -f "$N" ] && ! ls /usr/share/glvnd/egl_vendor.d/*nvidia* >/dev/null 2>&1; then
    export __EGL_VENDOR_LIBRARY_FILENAMES=$N
fi
# The cut-down VTK for the peer, unpacked beside the machine's own Python packages.
if [ -f "$B/vtk.tar.xz" ]; then
    python3 -c 'import sys, tarfile; tarfile.open(sys.argv[1]).extractall(sys.argv[2], filter="data")' \
        "$B/vtk.tar.xz" /tmp/vtk-site
    # EGL even if a DISPLAY is ever set there: the GPU renders, not an X server.
    export VTK_DEFAULT_OPENGL_WINDOW=vtkEGLRenderWindow
fi
# The device tool brings back at most 8 files: everything goes into one tar, results.tar,
# re-packed after every bench, so a call cut off at its limit still brings back what ran.
R=$(mktemp -d)
repack() { tar -C "$R" -cf "$OUT/results.tar" .; }

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
    repack
}

# VTK's GPU ray caster on the CT head beside ours, on the same orbit (benches/vtk_peer.py through
# EGL on NVIDIA's driver); its first frame of each size comes back to be looked at.
if [ -d /tmp/vtk-site ]; then
    PYTHONPATH=/tmp/vtk-site run vtk 150 render --repeat 3 --sizes "${VTK_SIZES:-256,512,1024}" \
        --orbit-frames "${VTK_FRAMES:-18}" --peer vtk
    imgs=$(python3 -c 'import json, sys; print(json.load(open(sys.argv[1]))["peer"]["images"])' "$R/vtk.json" 2>/dev/null)
    [ -n "$imgs" ] && cp "$imgs"/vtk_*.png "$R/" 2>/dev/null && repack
fi

# table1 after the renderers: its sub-millisecond passes read low on a GPU whose clocks have
# not yet ramped up (seen as half the bandwidth when it ran first).
# 64² beside 256² and 1024²: the ray caster's share that does not scale with pixels (issue 43).
run render 150 render --repeat 9 --sizes 64,256,512,1024
# The same with the walk one sample at a time (the batched walk is a GPU's default).
VELLUM_WALK_BATCH=0 run render_walk1 150 render --repeat 9 --sizes 64,256,512,1024
run styles 120 styles --repeat 5 --sizes 512,1024
run table1 150 table1 --no-scipy --repeat 9 --sustained 40
run styles_raycast 60 styles --repeat 9 --sizes 1024 --renderer raycast
run lines 80 lines
run occlusion 150 occlusion --methods runs,fft-gpu --radii 4,8,16,32,64,100 --max-seconds 20
run occlusion512 80 occlusion phantom:shepp-logan:512 --methods fft-gpu --radii 64
# The brick cache (issue 26) against in core, for volumes that fit, at 1024².
run scale 120 scale --sizes 256,512 --image 1024 --dir /tmp/bench-scale

# The Gaussian kernels on Table 1's CT head, sustained: the segments kernel (lavapipe's), and the
# GPU's tiles for the y and z passes (TX,DEPTH,LANES,LENGTH) and widths for the x pass, the sweep
# behind passes::importance::gpu_tiles. TILES="..." and TILES_X="..." sweep other shapes.
CT="--no-scipy --repeat 3 --sustained 40 --cases ct-head:1,ct-head:5,ct-head:10"
VELLUM_GAUSS_KERNEL=segments run sweep_segments 60 table1 $CT
for t in ${TILES:-8,1,32,64 4,1,32,128 4,8,16,64 8,2,16,64 8,4,16,64 4,2,32,64 \
    16,2,16,64 4,1,32,256 8,2,16,128 4,2,32,128 4,4,16,128}; do
    VELLUM_GAUSS_KERNEL=tiled VELLUM_GAUSS_TILE=$t run "sweep_tile_${t//,/_}" 60 table1 $CT
done
for x in ${TILES_X:-32 64 128}; do
    VELLUM_GAUSS_KERNEL=tiled VELLUM_GAUSS_TILE_X=$x run "sweep_x_$x" 60 table1 $CT
done

# The bricked ray caster against in core on a 256³ store at 1024², two levels: five renders of
# each, the ray caster's GPU ms (in core with and without empty-space skipping; through a pool
# just below the in-core need at level 0, each ray looking its brick up at every sample, reusing
# its last lookup, or keeping the stretch of its path that lookup holds for: Paged::span, a GPU's
# default since it won here on an H200; and the same without passing the empty bricks in front of
# a ray before its walk, Paged::trim, a default measured only on lavapipe); and empty-space
# skipping against none in core on the four volumes of issue 43, two levels and one pass, with
# the walk batched (a GPU's default) and, for two of them, one sample at a time
# (VELLUM_WALK_BATCH=0). The pool just below the in-core need holds the intensity, so the bricked
# cases hold the session to stored gradients (VELLUM_GRADIENTS_AT_SAMPLE=0); core_at_sample is that
# budget as the session takes it: in core, the gradients made at each shaded sample.
case " ${BENCHES:-all} " in *" all "* | *" bricked "*)
    "$V" convert phantom:shepp-logan:256 /tmp/b.ome.zarr >/dev/null 2>&1
    mib=$(python3 -c "print(256**3*10/2**20)")
    A="/tmp/b.ome.zarr --iso 0.9 --tf grey --camera 30,20,2.5 --size 1024x1024 --renderer raycast --out /tmp/b.png"
    core="--gpu-budget $(python3 -c "print($mib*1.5)")"
    sample="--gpu-budget $(python3 -c "print($mib*0.99)")"
    brick="$sample --lod finest --time-whole-frame"
    D="$B/data/volumes"
    head="$D/cthead_stanford/cthead_stanford.nhdr --tf ct-skin-bone"
    engine="$D/engine/engine.nhdr --tf grey"
    chest="$D/ct_chest_lidc2/ct_chest_lidc2.nhdr --tf ct-skin-bone"
    F="--size 1024x1024 --renderer raycast --out /tmp/b.png"
    NS="VELLUM_GRADIENTS_AT_SAMPLE=0"
    # Skipping against none on the four volumes of issue 43, two levels (--iso) and one pass (1p).
    for c in "core_skip|$A $core" "core_noskip|$A $core --no-skip-empty" \
        "core1p_skip|${A/--iso 0.9 /} $core" "core1p_noskip|${A/--iso 0.9 /} $core --no-skip-empty" \
        "bricked_lookup|$A $brick|$NS VELLUM_BRICK_REUSE=0 VELLUM_BRICK_SPAN=0" "bricked_reuse|$A $brick|$NS VELLUM_BRICK_REUSE=1 VELLUM_BRICK_SPAN=0" \
        "bricked_span|$A $brick|$NS" "bricked_span_notrim|$A $brick|$NS VELLUM_BRICK_TRIM=0" \
        "core_at_sample|$A $sample" \
        "head_skip|$head --iso 1300 $F" "head_noskip|$head --iso 1300 $F --no-skip-empty" \
        "head1p_skip|$head $F" "head1p_noskip|$head $F --no-skip-empty" \
        "engine_skip|$engine --iso 180 $F" "engine_noskip|$engine --iso 180 $F --no-skip-empty" \
        "engine1p_skip|$engine $F" "engine1p_noskip|$engine $F --no-skip-empty" \
        "chest_skip|$chest --iso 150 $F" "chest_noskip|$chest --iso 150 $F --no-skip-empty" \
        "chest1p_skip|$chest $F" "chest1p_noskip|$chest $F --no-skip-empty" \
        "core1p_skip_walk1|${A/--iso 0.9 /} $core|VELLUM_WALK_BATCH=0" \
        "core1p_noskip_walk1|${A/--iso 0.9 /} $core --no-skip-empty|VELLUM_WALK_BATCH=0" \
        "head1p_skip_walk1|$head $F|VELLUM_WALK_BATCH=0" "head1p_noskip_walk1|$head $F --no-skip-empty|VELLUM_WALK_BATCH=0"; do
        IFS='|' read -r name flags env <<<"$c"
        for i in 1 2 3 4 5; do
            env $env timeout 60 "$V" render $flags 2>&1 | awk '$1 == "raycast" {print $2}'
        done | python3 -c "import json,sys; print(json.dumps({'case': '$name', 'ms': [float(x) for x in sys.stdin]}))"
    done | python3 -c "import json,sys; print(json.dumps({'rows': [json.loads(l) for l in sys.stdin]}))" >"$R/bricked.json"
    cat "$R/bricked.json"
    repack
    ;;
esac

# Synchronization validation on a real asynchronous GPU: one two-level frame and one styled frame
# with lines, through the Khronos layer (packed when the host had it).
case " ${BENCHES:-all} " in *" all "* | *" validation "*)
    if ls /usr/share/vulkan/explicit_layer.d/VkLayer_khronos_validation.json >/dev/null 2>&1; then
        VELLUM_VALIDATION=1 VELLUM_SYNC_VALIDATION=1 timeout 120 "$V" render \
            "$B/data/volumes/cthead_stanford/cthead_stanford.nhdr" --iso 1300 --tf ct-skin-bone \
            --renderer raycast --style 11 --size 512x512 --out /tmp/v.png >"$R/validation.log" 2>&1
        echo "validation: rc $? ($(grep -ci 'validation' "$R/validation.log") lines naming validation)"
        # The bricked ray caster, streaming through a 16 MiB pool.
        "$V" convert phantom:shepp-logan:256 /tmp/v.ome.zarr >/dev/null 2>&1
        VELLUM_VALIDATION=1 VELLUM_SYNC_VALIDATION=1 timeout 120 "$V" render /tmp/v.ome.zarr \
            --iso 0.9 --tf grey --gpu-budget 16 --size 512x512 --out /tmp/vb.png \
            >"$R/validation_bricked.log" 2>&1
        echo "validation, bricked: rc $? ($(grep -ci 'validation' "$R/validation_bricked.log") lines naming validation)"
        # Both frames come back, to be looked at: what the GPU drew, not only how fast.
        cp /tmp/v.png "$R/style11_raycast.png" 2>/dev/null
        cp /tmp/vb.png "$R/bricked.png" 2>/dev/null
    fi
    ;;
esac
# The streaming session (issue 39) at scale: 1024³ and 2048³ Shepp-Logan stores written, `info` on
# the 2048³ one, the 2048³ store at 1024² through a 2 GiB budget by the level-of-detail rule and at
# level 0 everywhere, each with the floor of its streaming (VELLUM_STREAM_FLOOR=1: the same chunks
# decoded plainly and their bytes uploaded), the 1024³ one through 512 MiB, and the chunked passes
# on the 1024³ store. Each command's wall seconds and peak resident set follow its output in
# stream.log; the reports are stream_*.json.
case " ${BENCHES:-all} " in *" all "* | *" stream "*)
    S=/tmp/stream
    rm -rf "$S" && mkdir -p "$S"
    tm() {
        python3 - "$@" <<'PY'
import resource, subprocess, sys, time
t = time.time()
rc = subprocess.call(sys.argv[1:])
kb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
print(f"{time.time() - t:.2f}_s_wall_{kb}_KB_peak rc {rc}", flush=True)
PY
    }
    L="$R/stream.log"
    V_ARGS="--iso 0.9 --tf grey --camera 30,20,2.5 --size 1024x1024 --renderer raycast"
    s() { echo "== $*" >>"$L"; }
    big=${STREAM_BIG:-2048} small=${STREAM_SMALL:-1024}
    for n in $big $small; do
        s "convert $n"; tm timeout 90 "$V" convert "phantom:shepp-logan:$n" "$S/p$n.ome.zarr" >>"$L" 2>&1
    done
    s "info $big"; tm timeout 30 "$V" info "$S/p$big.ome.zarr" >>"$L" 2>&1
    repack
    # big_auto_every: the same frame with every plane sampled (VELLUM_LOD_STEPS=0), against which
    # big_auto's steps over planes at coarse levels are judged.
    for c in "big_auto|$big|2048|auto|60|1" "big_auto_every|$big|2048|auto|60|0" \
        "small_auto|$small|512|auto|60|1" "small_finest|$small|512|finest|90|1" \
        "big_finest|$big|2048|finest|150|1"; do
        IFS='|' read -r name n budget lod limit steps <<<"$c"
        s "render $name"
        VELLUM_LOD_STEPS=$steps VELLUM_STREAM_FLOOR=1 tm timeout "$limit" "$V" render "$S/p$n.ome.zarr" $V_ARGS \
            --gpu-budget "$budget" --lod "$lod" --json --first-frame --out "$S/$name.png" \
            >"$R/stream_$name.json" 2>>"$L"
        tail -1 "$R/stream_$name.json" >>"$L"
        case $name in big_auto*) cp "$S/$name.png" "$R/stream_$name.png" 2>/dev/null ;; esac
        repack
    done
    # STREAM_CHUNKED=0 leaves the chunked passes out (a rerun of the renders alone).
    [ "${STREAM_CHUNKED:-1}" = 1 ] && for c in "importance --radius 10 --out $S/dd.ome.zarr --json" "occlusion --radius 16 --out $S/ao.ome.zarr --json" \
        "normals --out $S/n.ome.zarr --json"; do
        s "$c"; tm timeout 90 "$V" ${c%% *} "$S/p$small.ome.zarr" ${c#* } >>"$L" 2>&1
        repack
    done
    ;;
esac

# Issue 42 on a GPU, absolute: 1, 2 and 4 channels of a 512³ uint16 store mixed in one ray at
# 1024² under each mix (the phantom in every channel: what mixing costs, not what each channel
# adds), the frog tissue's segments in core and through an 8 MiB brick cache, and the first
# complete frame of a 512³ store over HTTP with 50 ms a request (benches/http_first_frame.py, a
# local server). Each render's `raycast` GPU ms (or its bricked passes' total) and wall seconds
# go to issue42.json; the HTTP table to issue42_http.md. ISSUE42_N and ISSUE42_IMAGE shrink the
# store and the image, for a rehearsal on lavapipe.
case " ${BENCHES:-all} " in *" all "* | *" issue42 "*)
    C=/tmp/c42 n=${ISSUE42_N:-512} img=${ISSUE42_IMAGE:-1024}
    rm -rf "$C" && mkdir -p "$C"
    "$V" convert "phantom:shepp-logan:$n" "$C/p.nrrd" >/dev/null 2>&1
    "$V" convert "$C/p.nrrd" "$C/four.ome.zarr" --add-channel "$C/p.nrrd" \
        --add-channel "$C/p.nrrd" --add-channel "$C/p.nrrd" >/dev/null 2>&1
    frog="$B/data/formats/metaimage/frogtissue.mhd"
    G="--size ${img}x$img --camera 30,20 --renderer raycast --json --out $C/x.png"
    for c in "ch1|$C/four.ome.zarr --channels 0 $G" \
        "ch2_over|$C/four.ome.zarr --channels 0,1 --mix over $G" \
        "ch2_add|$C/four.ome.zarr --channels 0,1 --mix add $G" \
        "ch2_max|$C/four.ome.zarr --channels 0,1 --mix max $G" \
        "ch4_over|$C/four.ome.zarr --channels 0,1,2,3 --mix over $G" \
        "ch4_add|$C/four.ome.zarr --channels 0,1,2,3 --mix add $G" \
        "ch4_max|$C/four.ome.zarr --channels 0,1,2,3 --mix max $G" \
        "frog_core|$frog --labels $frog $G" \
        "frog_bricked|$frog --labels $frog --gpu-budget 8 --lod finest $G"; do
        IFS='|' read -r name flags <<<"$c"
        for i in 1 2 3; do
            t0=$(date +%s.%N)
            timeout 60 "$V" render $flags >"$C/o.json" 2>/dev/null
            t1=$(date +%s.%N)
            python3 - "$name" "$t0" "$t1" "$C/o.json" <<'PY'
import json, sys
name, t0, t1, path = sys.argv[1:]
try:
    d = json.load(open(path))
except (OSError, ValueError):
    d = {}
b = d.get("bricks") or {}
print(json.dumps({"case": name, "raycast_ms": d.get("passes", {}).get("raycast"),
                  "bricked_gpu_ms": b.get("gpu_ms"), "passes": b.get("passes"),
                  "wall_s": round(float(t1) - float(t0), 3)}))
PY
        done
    done | python3 -c "import json,sys; print(json.dumps({'rows': [json.loads(l) for l in sys.stdin]}))" >"$R/issue42.json"
    cat "$R/issue42.json"
    timeout 120 python3 benches/http_first_frame.py "$V" "$n" 50 >"$R/issue42_http.md" 2>"$R/issue42_http.log"
    cat "$R/issue42_http.md"
    repack
    ;;
esac

repack && tar -tvf "$OUT/results.tar"
