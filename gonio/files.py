"""Reading a file that a user named (a config, a MATERIALS list, a measured material's table).

A name from outside may point anywhere: at a folder, at ``/dev/zero`` or a pipe that never ends, at a
file far larger than anything of its kind. :func:`read_named_file` reads only a regular file, and only
up to a bound fitted to what it should hold, so that a wrong path is one clear line and never a process
that fills the memory until the kernel kills it.
"""

from __future__ import annotations

import os
import stat

__all__ = ["NamedFileError", "read_named_file"]


class NamedFileError(ValueError):
    """A named file that cannot be read as asked; the message is the reason alone ("no such file", "is a
    folder", ...), for the caller to put after the name it knows the file by."""


def read_named_file(path, max_bytes: int, noun: str = "file") -> bytes:
    """The bytes of the regular file at ``path``, at most ``max_bytes`` of them.

    Parameters
    ----------
    path : str or os.PathLike
        What the user gave.
    max_bytes : int
        The most a file of its kind can hold; a larger one is refused before it is read.
    noun : str
        What the file should be ("config file", "MERL table"): the reasons name it.

    Raises
    ------
    NamedFileError
        ``no such {noun}``, ``is a folder, not a {noun}``, ``is not a regular file (a device, a pipe or
        a socket)``, ``has N bytes; a {noun} has at most M``, ``permission denied``, or the system's
        reason.
    """
    try:
        # O_NONBLOCK: opening a pipe that no one writes returns at once (and is refused below) instead of
        # waiting for a writer; a regular file reads as usual.
        fd = os.open(os.fspath(path), os.O_RDONLY | os.O_CLOEXEC | os.O_NONBLOCK)
    except FileNotFoundError:
        raise NamedFileError(f"no such {noun}") from None
    except IsADirectoryError:
        raise NamedFileError(f"is a folder, not a {noun}") from None
    except PermissionError:
        raise NamedFileError("permission denied") from None
    except OSError as exc:
        raise NamedFileError(f"cannot be opened ({exc.strerror or exc})") from None
    try:
        st = os.fstat(fd)
        if stat.S_ISDIR(st.st_mode):
            raise NamedFileError(f"is a folder, not a {noun}")
        if not stat.S_ISREG(st.st_mode):
            raise NamedFileError("is not a regular file (a device, a pipe or a socket)")
        if st.st_size > max_bytes:
            raise NamedFileError(f"has {st.st_size:,} bytes; a {noun} has at most {max_bytes:,}")
        chunks, left = [], max_bytes + 1
        while left > 0:
            chunk = os.read(fd, min(left, 1 << 24))
            if not chunk:
                break
            chunks.append(chunk)
            left -= len(chunk)
        data = b"".join(chunks)
    except OSError as exc:
        raise NamedFileError(f"cannot be read ({exc.strerror or exc})") from None
    finally:
        os.close(fd)
    if len(data) > max_bytes:   # it grew while we read it
        raise NamedFileError(f"has more than {max_bytes:,} bytes; a {noun} has at most {max_bytes:,}")
    return data
