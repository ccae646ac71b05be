# homofac: `make run` runs the default factorization, `make test` runs the test suite.
# Both create .venv when it is missing and install the package with its dev extra into it.

PYTHON ?= python3
VENV   ?= .venv
PY      = $(VENV)/bin/python
STAMP   = $(VENV)/.homofac-installed
# Debian packages the headless OpenGL preview needs (EGL through Mesa llvmpipe).
SYSTEM_PACKAGES = libegl1 libgl1 libgles2
PYTEST_ARGS ?=

.PHONY: run test install system-packages benchmark clean

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

test: $(STAMP) system-packages
	$(PY) -m pytest -q $(PYTEST_ARGS)

# Run time against error (issue 5): HOMOFAC_BENCH_LEVELS=preview,default,high make benchmark for the thesis run.
benchmark: $(STAMP)
	$(PY) -m pytest benchmarks -q -p no:cacheprovider --benchmark-json=benchmarks/results.json
	$(PY) benchmarks/report.py benchmarks/results.json --readme README.md

clean:
	rm -rf out .pytest_cache
