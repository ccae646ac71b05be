"""``python -m homofac.bake ENVIRONMENT --out DIR``: bake an environment for every glTF material.

An entry point, not part of the library: it runs :func:`homofac.app.bake_cli.main`. The app layer is
looked up by name so that the library package ``homofac.bake`` never depends on the layer above it.
"""

import importlib
import sys

if __name__ == "__main__":
    sys.exit(importlib.import_module("homofac.app.bake_cli").main())
