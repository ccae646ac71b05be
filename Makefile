# homofac: `make run` runs the default factorization, `make test` the fast test suite, `make test-all`
# all of it, `make docs` the documentation site. Each creates .venv when it is missing and installs the
# package with its dev and gl extras into it (and `make test*` the system packages the tests need).

PYTHON ?= python3
VENV   ?= .venv
PY      = $(VENV)/bin/python
STAMP   = $(VENV)/.homofac-installed
# Debian packages the headless OpenGL preview needs (EGL through Mesa llvmpipe).
SYSTEM_PACKAGES = libegl1 libgl1 libgles2
PYTEST_ARGS ?=

.PHONY: run test test-slow test-all docs install system-packages benchmark clean

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[dev,gl]"
	@touch $(STAMP)

install: $(STAMP)

run: $(STAMP)
	$(PY) -m homofac.fit --out out

# Installs the system libraries the GL tests need when they are missing (root or sudo).
system-packages:
	@if ! /sbin/ldconfig -p 2>/dev/null | grep -q 'libEGL.so.1'; then \
		SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
		$$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq $(SYSTEM_PACKAGES); \
	fi

# Two workers (one per core); a test file's tests stay on one worker so module fixtures are built once.
XDIST = -n 2 --dist loadfile

test: $(STAMP) system-packages
	$(PY) -m pytest -q $(XDIST) -m "not slow" $(PYTEST_ARGS)

# The tests marked slow (stress cases, subprocess CLI runs, the notebook, the docs build ...).
test-slow: $(STAMP) system-packages
	$(PY) -m pytest -q $(XDIST) -m slow $(PYTEST_ARGS)

test-all: $(STAMP) system-packages
	$(PY) -m pytest -q $(XDIST) $(PYTEST_ARGS)

# The documentation site into site/ (warnings are errors).
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(PY) -m mkdocs build --strict --site-dir site

# Run time against error (issue 5): HOMOFAC_BENCH_LEVELS=preview,default,high make benchmark for the thesis run.
benchmark: $(STAMP)
	$(PY) -m pytest benchmarks -q -p no:cacheprovider --benchmark-json=benchmarks/results.json
	$(PY) benchmarks/report.py benchmarks/results.json --readme README.md

clean:
	rm -rf out site .pytest_cache .cache
