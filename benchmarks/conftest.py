"""Benchmarks (not part of `make test`): `make benchmark`, or
`HOMOFAC_BENCH_LEVELS=preview,default,high .venv/bin/pytest benchmarks --benchmark-json=benchmarks/results.json`."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
