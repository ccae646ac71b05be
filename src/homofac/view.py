"""``python -m homofac.view OUT_DIR [--html FILE.html]``: a self-contained WebGL2 viewer of a factorization.

Writes one HTML file (default ``OUT_DIR/viewer.html``; textures, meshes and the exact images embedded)
that shows the factorization in ``OUT_DIR`` (written by ``python -m homofac.fit``) live in WebGL2 on a
sphere and a torus under an orbit camera, beside the exact lighting of the reference view (rebuilt
from the recorded config) and an error heat map, with per-term toggles and exposure. An entry point
over :func:`homofac.app.cli.view_main` (the page: :mod:`homofac.app.view`).
"""

import sys

from homofac.app.cli import view_main as main

if __name__ == "__main__":
    sys.exit(main())
