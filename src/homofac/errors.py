"""The one exception type homofac raises for bad input or an impossible request.

Every message is a single line that names the offending key, file or value, so the CLI can print
it as is (``homofac: error: <message>``) without a traceback.
"""

from __future__ import annotations


class HomofacError(ValueError):
    """Bad input or an impossible request; the message is one line naming the problem."""


def require(condition: bool, message: str) -> None:
    """Raise :class:`HomofacError` with ``message`` unless ``condition`` holds."""
    if not condition:
        raise HomofacError(message)
