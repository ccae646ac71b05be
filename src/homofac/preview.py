"""``python -m homofac.preview OUT_DIR [-o FILE.png] [--window]``: look at a factorization.

Renders the factorization in ``OUT_DIR`` (written by ``python -m homofac.fit``) on a sphere, a torus
or a mesh file headless through EGL, beside the exact lighting (rebuilt from the recorded config) and
an error heat map, and writes the picture as a PNG (default ``OUT_DIR/preview.png``). ``--window``
opens the interactive viewer instead. An entry point over :func:`homofac.app.cli.preview_main`.
"""

import sys

from homofac.app.cli import preview_main as main

if __name__ == "__main__":
    sys.exit(main())
