"""gonio: control and acquisition for gonio-reflectometers (README.md, docs/).

Importing :mod:`gonio` imports nothing else: each module pulls in what it needs.
"""

from __future__ import annotations

__all__ = ["software_version"]


def software_version() -> str:
    """The installed version of gonio (``0+unknown`` in a source tree that was never installed)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("gonio")
    except PackageNotFoundError:
        return "0+unknown"
