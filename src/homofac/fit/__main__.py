"""``python -m homofac.fit [CONFIG.yaml] [--out DIR]``: run a factorization from a YAML config.

An entry point, not part of the library: it runs :func:`homofac.app.cli.fit_main`. The app layer is
looked up by name so that the library package ``homofac.fit`` never depends on the layer above it.
"""

import importlib
import sys

if __name__ == "__main__":
    sys.exit(importlib.import_module("homofac.app.cli").fit_main())
