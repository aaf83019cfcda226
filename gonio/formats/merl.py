"""MERL ``.binary`` BRDF tables: read and write.

Layout (shared/references/FORMATS.md; wdas/brdf ``BRDFMeasuredMERL.cpp``): three little-endian int32 bin
counts 90 (θh), 90 (θd), 180 (φd), then three float64 planes R, G, B of 1,458,000 values each, flat index
``iφd + 180·(iθd + 90·iθh)`` (:func:`gonio.geometry.merl_index`). Stored values are scaled on read,
R × 1/1500, G × 1.15/1500, B × 1.66/1500, to f_r in sr⁻¹ (no cosine factor); writers divide by the same
factors. A negative value means "no data" (below the horizon, or not measured). The format has no room for
metadata: units, cosine convention and provenance go in the export report instead.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from gonio.files import NamedFileError, read_named_file
from gonio.geometry import MERL_SHAPE

from . import atomic_path

__all__ = ["MERL_SCALE", "MERL_BINS", "MERL_FILE_BYTES", "read_merl", "parse_merl", "write_merl"]

#: Multipliers from stored values to f_r in sr⁻¹, per channel (R, G, B).
MERL_SCALE = (1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0)
#: Bins per channel: 90 · 90 · 180.
MERL_BINS = MERL_SHAPE[0] * MERL_SHAPE[1] * MERL_SHAPE[2]
_HEADER_BYTES = 12
#: Size of a whole file in bytes (12-byte header, 3 × 1,458,000 float64).
MERL_FILE_BYTES = _HEADER_BYTES + 3 * MERL_BINS * 8


def read_merl(path: str | Path) -> np.ndarray:
    """The scaled table of a MERL file (:func:`parse_merl` of its bytes).

    Parameters
    ----------
    path : str or Path
        A ``.binary`` file of exactly :data:`MERL_FILE_BYTES` bytes.

    Returns
    -------
    numpy.ndarray, shape (3, 1458000), float64
        f_r in sr⁻¹ per channel (R, G, B), flat MERL index order. No-data entries stay negative.

    Raises
    ------
    ValueError
        Naming the file, when it cannot be read, has the wrong size or the wrong header.
    """
    path = os.fspath(path)
    try:
        data = read_named_file(path, MERL_FILE_BYTES, "MERL table")
    except NamedFileError as exc:
        raise ValueError(f"merl: cannot read file {path!r}: {exc}") from None
    return parse_merl(data, path)


def parse_merl(data: bytes, name: str) -> np.ndarray:
    """The scaled table of the MERL file whose bytes are ``data`` (``name`` is what errors call it); as
    :func:`read_merl`."""
    if len(data) != MERL_FILE_BYTES:
        raise ValueError(f"merl: file {name!r} has {len(data)} bytes; a MERL table has {MERL_FILE_BYTES} "
                         f"(12-byte header, 3 × {MERL_BINS} float64)")
    header = np.frombuffer(data, dtype="<i4", count=3)
    if tuple(int(v) for v in header) != MERL_SHAPE:
        raise ValueError(f"merl: file {name!r} has header {tuple(int(v) for v in header)}, "
                         f"expected {MERL_SHAPE}")
    planes = np.frombuffer(data, dtype="<f8", offset=_HEADER_BYTES).reshape(3, MERL_BINS)
    return planes * np.asarray(MERL_SCALE)[:, None]


def write_merl(path: str | Path, fr: np.ndarray) -> Path:
    """Write a MERL table (atomically: a temporary file in the same folder, then a rename).

    Parameters
    ----------
    path : str or Path
        Output file (conventionally ``*.binary``).
    fr : array_like, shape (3, 1458000)
        f_r in sr⁻¹ per channel (R, G, B) in flat MERL index order. NaN and negative entries are
        written as −1 (stored units), MERL's "no data".

    Returns
    -------
    Path
        ``path``.
    """
    fr = np.asarray(fr, dtype=np.float64)
    if fr.shape != (3, MERL_BINS):
        raise ValueError(f"merl: table must have shape (3, {MERL_BINS}) (R, G, B × bins), got {fr.shape}")
    path = Path(path)
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(np.asarray(MERL_SHAPE, dtype="<i4").tobytes())
        # One channel at a time, written from the array itself: the whole table scaled, masked, made
        # contiguous and turned into bytes was four 35 MB arrays of fresh pages.
        for channel, scale in zip(fr, MERL_SCALE, strict=True):
            stored = channel / scale
            stored = np.where(np.isfinite(stored) & (stored >= 0.0), stored, -1.0).astype("<f8", copy=False)
            fh.write(memoryview(np.ascontiguousarray(stored)))
    return path
