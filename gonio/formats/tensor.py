"""The ``tensor_file`` container: named, typed, n-dimensional arrays in one binary file.

This is the container of Mitsuba 3's and pbrt-v4's measured BSDFs (the RGL ``.bsdf`` files of Dupuy &
Jakob 2018); :mod:`gonio.formats.rgl` says which fields a measured BSDF holds. Layout (little-endian;
shared/references/FORMATS.md, after mitsuba3 ``src/core/tensor.cpp``):

- the 12 bytes ``tensor_file\\0``, u8 major version 1, u8 minor version 0, u32 field count;
- per field: u16 name length, the name (UTF-8), u16 ndim, u8 dtype code (1 u8, 2 i8, 3 u16, 4 i16,
  5 u32, 6 i32, 7 u64, 8 i64, 9 f16, 10 f32, 11 f64), u64 absolute offset of the data, ndim × u64 shape;
- the data of each field in C order, starting at an 8-byte aligned offset.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from gonio.files import NamedFileError, read_named_file

from . import atomic_path

__all__ = ["read_tensor", "parse_tensor", "write_tensor", "DTYPE_CODES"]

MAGIC = b"tensor_file\0"
VERSION = (1, 0)
#: dtype code → numpy dtype (little-endian).
DTYPE_CODES = {1: "u1", 2: "i1", 3: "<u2", 4: "<i2", 5: "<u4", 6: "<i4", 7: "<u8", 8: "<i8", 9: "<f2",
               10: "<f4", 11: "<f8"}
_CODE_OF = {np.dtype(v).newbyteorder("<").str: k for k, v in DTYPE_CODES.items()}
_ALIGN = 8


def _code(name: str, array: np.ndarray) -> int:
    key = array.dtype.newbyteorder("<").str if array.dtype.byteorder != "|" else array.dtype.str
    code = _CODE_OF.get(key)
    if code is None:
        raise ValueError(f"tensor field {name!r}: dtype {array.dtype} is not storable; allowed: u8, i8, u16, "
                         "i16, u32, i32, u64, i64, f16, f32, f64")
    return code


def write_tensor(path: str | Path, fields: dict[str, np.ndarray]) -> Path:
    """Write named arrays to a tensor file (atomically: a temporary file, then a rename).

    Parameters
    ----------
    path : str or Path
        Output file.
    fields : dict of str to numpy.ndarray
        Name → array (any storable dtype, 0 to 65535 dimensions), written in the dict's order.

    Returns
    -------
    Path
        ``path``.
    """
    arrays = {str(k): np.ascontiguousarray(v) for k, v in fields.items()}
    header = bytearray(MAGIC + struct.pack("<BBI", *VERSION, len(arrays)))
    entries = []
    for name, a in arrays.items():
        raw = name.encode("utf-8")
        if not raw or len(raw) > 0xFFFF:
            raise ValueError(f"tensor field name {name!r}: must be 1 to 65535 bytes of UTF-8")
        entries.append((raw, a, _code(name, a)))
        header += struct.pack("<H", len(raw)) + raw + struct.pack("<HB", a.ndim, 0) + b"\0" * 8
        header += b"\0" * (8 * a.ndim)
    # Second pass now that the header's length (and so every data offset) is known.
    offset = -(-len(header) // _ALIGN) * _ALIGN
    header = bytearray(MAGIC + struct.pack("<BBI", *VERSION, len(arrays)))
    offsets = []
    for raw, a, code in entries:
        offsets.append(offset)
        header += struct.pack("<H", len(raw)) + raw + struct.pack("<HBQ", a.ndim, code, offset)
        header += struct.pack(f"<{a.ndim}Q", *a.shape)
        offset = -(-(offset + a.nbytes) // _ALIGN) * _ALIGN
    path = Path(path)
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(header)
        for (_, a, _), start in zip(entries, offsets, strict=True):
            fh.write(b"\0" * (start - fh.tell()))
            fh.write(a.astype(a.dtype.newbyteorder("<"), copy=False).tobytes())
    return path


#: The largest tensor file read: RGL's measured .bsdf files are 1-100 MB; a name that points at a device or
#: at some other huge file is refused, not read into memory.
TENSOR_MAX_BYTES = 1 << 30


def read_tensor(path: str | Path) -> dict[str, np.ndarray]:
    """Read every field of a tensor file (:func:`parse_tensor` of its bytes).

    Raises
    ------
    ValueError
        Naming the file and what is wrong (unreadable, magic, version, dtype code, a field past the end).
    """
    path = Path(path)
    try:
        data = read_named_file(path, TENSOR_MAX_BYTES, "tensor file")
    except NamedFileError as exc:
        raise ValueError(f"tensor file {str(path)!r}: cannot read: {exc}") from None
    return parse_tensor(data, str(path))


def parse_tensor(data: bytes, name: str) -> dict[str, np.ndarray]:
    """Every field of the tensor file whose bytes are ``data`` (``name`` is what errors call it).

    Returns
    -------
    dict of str to numpy.ndarray
        Name → array (native byte order), in the file's order.

    Raises
    ------
    ValueError
        Naming the file and what is wrong (magic, version, dtype code, a truncated header, a field past
        the end).
    """
    if data[:12] != MAGIC or len(data) < 18:
        raise ValueError(f"tensor file {name!r}: does not start with 'tensor_file\\0'")
    major, minor, count = struct.unpack_from("<BBI", data, 12)
    if (major, minor) != VERSION:
        raise ValueError(f"tensor file {name!r}: version {major}.{minor}; allowed: 1.0")
    pos, out = 18, {}
    try:
        for _ in range(count):
            (length,) = struct.unpack_from("<H", data, pos)
            field = data[pos + 2:pos + 2 + length].decode("utf-8")
            pos += 2 + length
            ndim, code, offset = struct.unpack_from("<HBQ", data, pos)
            pos += 11
            shape = struct.unpack_from(f"<{ndim}Q", data, pos)
            pos += 8 * ndim
            if code not in DTYPE_CODES:
                raise ValueError(f"tensor file {name!r}: field {field!r} has dtype code {code}; "
                                 "allowed: 1..11")
            dtype = np.dtype(DTYPE_CODES[code])
            nbytes = int(np.prod(shape, dtype=object)) * dtype.itemsize
            if offset + nbytes > len(data):
                raise ValueError(f"tensor file {name!r}: field {field!r} runs past the end of the file")
            out[field] = np.frombuffer(data, dtype=dtype, count=nbytes // dtype.itemsize,
                                       offset=offset).reshape(shape).astype(dtype.newbyteorder("="))
    except (struct.error, UnicodeDecodeError):
        raise ValueError(f"tensor file {name!r}: its header is cut short or garbled") from None
    return out
