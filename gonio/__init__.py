"""gonio: control and acquisition for gonio-reflectometers (README.md, docs/).

Importing :mod:`gonio` imports nothing else: each module pulls in what it needs.
"""

from __future__ import annotations

__all__ = ["software_version"]


def software_version() -> str:
    """The installed version of gonio (``0+unknown`` in a source tree that was never installed).

    What :func:`importlib.metadata.version` answers, read from the first ``gonio-*.dist-info`` on
    ``sys.path`` without importing :mod:`importlib.metadata` (with the email, zip and csv modules it
    pulls in: about 0.04 s of CPU, more than `gonio export --format csv` spends on its work); anything
    but that plain case (an egg-info, a zip on the path, another finder of distributions, two
    candidates in one folder) is left to :mod:`importlib.metadata`."""
    version = _dist_info_version()
    if version is not None:
        return version
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("gonio")
    except PackageNotFoundError:
        return "0+unknown"


def _dist_info_version() -> str | None:
    import os
    import sys
    from importlib.machinery import PathFinder

    if any(f is not PathFinder and hasattr(f, "find_distributions") for f in sys.meta_path):
        return None
    for entry in sys.path:
        if not isinstance(entry, str):
            return None
        folder = entry or "."
        if folder.lower().endswith(".egg"):   # an egg's own metadata: importlib.metadata's case
            return None
        try:
            names = os.listdir(folder)
        except OSError:
            if os.path.exists(folder):   # a zip, or a folder we may not list: importlib.metadata's case
                return None
            continue
        found = [n for n in names if n.lower().endswith((".dist-info", ".egg-info"))
                 and n.lower().rpartition(".")[0].partition("-")[0].replace(".", "_").replace("-", "_")
                 == "gonio"]
        if not found:
            continue
        if len(found) != 1 or not found[0].lower().endswith(".dist-info"):
            return None
        try:
            with open(os.path.join(folder, found[0], "METADATA"), encoding="utf-8") as f:
                for line in f:
                    if not line.strip():
                        break          # the headers end at the first empty line
                    if line.startswith("Version:"):
                        return line.partition(":")[2].strip()
        except OSError:
            return None
        return None
    return None
