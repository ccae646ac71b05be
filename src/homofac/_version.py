"""The version of homofac (written into every factorization.json and shader)."""

__version__ = "0.2.0"
