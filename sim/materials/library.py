"""Measured materials by name from one folder: what ``gonio serve --materials DIR`` serves.

Through the daemon a measured material is named, never pathed: ``bsdf:NAME`` and ``merl:NAME`` are
files of DIR, and without a folder they are refused. NAME is a file name of DIR itself: letters,
digits, ``.``, ``_`` and ``-``, not starting with ``.``, at most 128 characters (so never ``..``, an
absolute path or a sub-folder). A name is served only when it is a regular file no larger than its
model's cap, which is checked before the file is opened: ``lstat`` relative to DIR's own descriptor
(a link, FIFO, device, socket or folder is refused unopened, so a FIFO cannot block a reader and
``/dev/zero`` cannot fill the memory); then it is opened with ``O_NOFOLLOW | O_NONBLOCK``, checked again
with ``fstat`` (the same file, still regular) and read up to its cap and one byte more.

Every reason a name cannot be served (missing, a link, not a regular file, too large, unreadable) gives
the same message, so that no request can learn whether some file exists. Analytic materials
(``lambert:...``, ``ggx:...``) pass through to :func:`gonio.sim.materials.load`.
"""

from __future__ import annotations

import os
import re
import stat
from pathlib import Path

from gonio.formats.merl import MERL_FILE_BYTES, parse_merl
from gonio.formats.tensor import parse_tensor

from .base import Material
from .bsdf_file import MeasuredTensor
from .merl import Merl
from .spec import split_spec

__all__ = ["MaterialsFolder", "FILE_MODELS", "MAX_TENSOR_BYTES"]

#: The largest tensor file served (RGL's measured BSDFs are 1-30 MB).
MAX_TENSOR_BYTES = 256 * 1024 * 1024
#: Models that name a file, and the most bytes one may hold.
FILE_MODELS = {"bsdf": MAX_TENSOR_BYTES, "merl": MERL_FILE_BYTES}
_NAME = re.compile(r"^[A-Za-z0-9_-][A-Za-z0-9._-]{0,127}$")
_CHUNK = 1 << 20


class MaterialsFolder:
    """The folder measured materials are served from (``root``), or none (``root=None``: refused).

    Examples
    --------
    >>> MaterialsFolder(None).load("lambert:albedo=0.5").spec
    'lambert:albedo=0.5'
    >>> MaterialsFolder(None).load("merl:/etc/passwd")
    Traceback (most recent call last):
    ...
    ValueError: merl:NAME names a measured material; this daemon serves none (start it with --materials DIR)
    """

    def __init__(self, root: str | Path | None):
        self.root = None if root is None else Path(root)

    def check(self) -> None:
        """ValueError naming ``--materials`` unless the folder exists (the daemon checks it at start)."""
        if self.root is not None and not self.root.is_dir():
            raise ValueError(f"--materials: {self.root} is not a folder")

    def load(self, spec: str) -> Material:
        """The material ``spec`` describes; ``bsdf:NAME`` and ``merl:NAME`` from the folder (ValueError,
        one message whatever the reason, when NAME cannot be served)."""
        model, rest = split_spec(spec)
        if model not in FILE_MODELS:
            from . import load

            return load(spec)
        data = self.read(model, rest)
        if model == "merl":
            return Merl(f"merl:{rest}", rest, parse_merl(data, rest))
        return MeasuredTensor.from_fields(f"bsdf:{rest}", rest, parse_tensor(data, rest))

    def check_name(self, model: str, name: str) -> None:
        """ValueError unless this folder could serve ``name`` by its spelling alone (no file is looked at)."""
        if self.root is None:
            raise ValueError(f"{model}:NAME names a measured material; this daemon serves none (start it "
                             "with --materials DIR)")
        if not _NAME.match(name):
            raise ValueError(f"{model}: expected the name of a file in the daemon's materials folder "
                             f"(letters, digits, '.', '_', '-'), never a path; got {name[:200]!r}")

    def read(self, model: str, name: str) -> bytes:
        """The bytes of ``name`` for ``model`` (see the module docstring for what is refused)."""
        self.check_name(model, name)
        cap = FILE_MODELS[model]
        what = "a MERL table of exactly" if model == "merl" else "a regular file of at most"
        missing = ValueError(f"{model}:{name}: no such material in the daemon's materials folder ({what} "
                             f"{cap:,} bytes)")
        try:
            folder = os.open(self.root, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
        except OSError:
            raise missing from None
        try:
            try:
                before = os.stat(name, dir_fd=folder, follow_symlinks=False)
            except OSError:
                raise missing from None
            if not _servable(before, model, cap):
                raise missing
            try:
                fd = os.open(name, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC, dir_fd=folder)
            except OSError:
                raise missing from None
        finally:
            os.close(folder)
        try:
            now = os.fstat(fd)
            if (now.st_dev, now.st_ino) != (before.st_dev, before.st_ino) or not _servable(now, model, cap):
                raise missing
            chunks, size = [], 0
            while size <= cap:
                chunk = os.read(fd, min(_CHUNK, cap + 1 - size))
                if not chunk:
                    break
                chunks.append(chunk)
                size += len(chunk)
        except OSError:
            raise missing from None
        finally:
            os.close(fd)
        if size > cap:
            raise missing
        return b"".join(chunks)


def _servable(st: os.stat_result, model: str, cap: int) -> bool:
    if not stat.S_ISREG(st.st_mode):
        return False
    return st.st_size == cap if model == "merl" else st.st_size <= cap
