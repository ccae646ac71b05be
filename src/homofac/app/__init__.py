"""homofac.app: the top layer: the YAML config (assembled from the layers' option models), the memory
budget, a run (target -> factorization -> output directory), and the command-line tools."""

from __future__ import annotations

from . import budget, cli, config, run
from .config import Config, load, parse
from .run import build_target, target_from_config

__all__ = ["Config", "budget", "build_target", "cli", "config", "load", "parse", "run", "target_from_config"]
