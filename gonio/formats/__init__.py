"""File formats that renderers and tools read, written and read by our own code.

- :mod:`.merl`: MERL ``.binary`` tables (Matusik et al. 2003), f_r on 90 × 90 × 180 half/difference bins.
- :mod:`.tensor`: the ``tensor_file`` container of named typed arrays (Mitsuba 3, pbrt-v4, RGL ``.bsdf``).
- :mod:`.rgl`: the layout of a measured BSDF inside a tensor file (Dupuy & Jakob 2018): its warps, and a
  writer that acts as a virtual gonio-reflectometer over any BRDF.
- :mod:`.radiance`: PAB-Opto text files, one per incidence, for Radiance's ``pabopto2bsdf``.
- :mod:`.csv`: one row per sample with a header that gives the units.

Every writer writes to a temporary name in the target folder and renames it into place
(:func:`atomic_path`), so a reader never sees a half-written file.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

__all__ = ["atomic_path"]


@contextlib.contextmanager
def atomic_path(path: str | Path):
    """Yield a temporary path beside ``path``; on success rename it to ``path``, on error delete it.

    The temporary file is in the target folder, so the rename is atomic on POSIX file systems.
    """
    path = Path(path)
    if not path.parent.is_dir():
        raise ValueError(f"output {str(path)!r}: folder {str(path.parent)!r} does not exist")
    tmp = path.with_name(f".{path.name}.{os.getpid()}.partial")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
