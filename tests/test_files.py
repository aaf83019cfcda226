"""A file a user names is read only when it is a regular file of a size its kind can have: a folder, a device
that never ends (/dev/zero), a pipe no one writes, or a file far past the bound is one clear line, at once."""

from __future__ import annotations

import os

import pytest

from gonio.cli import main
from gonio.files import NamedFileError, read_named_file
from gonio.formats.merl import read_merl
from gonio.formats.tensor import read_tensor


def test_a_regular_file_is_read_whole(tmp_path):
    path = tmp_path / "a.toml"
    path.write_bytes(b"x" * 1000)
    assert read_named_file(path, 1000) == b"x" * 1000


@pytest.mark.parametrize("make, reason", [
    (lambda p: None, "no such config file"),
    (lambda p: p.mkdir(), "is a folder, not a config file"),
    (lambda p: os.mkfifo(p), "is not a regular file"),       # no writer: opening it must not wait for one
    (lambda p: (p.touch(), os.truncate(p, 1001)), "has 1,001 bytes; a config file has at most 1,000"),
])
def test_what_is_not_a_small_regular_file_is_refused_with_its_reason(tmp_path, make, reason):
    path = tmp_path / "named"
    make(path)
    with pytest.raises(NamedFileError, match=f"^{reason}"):
        read_named_file(path, 1000, "config file")


def test_devices_are_refused_before_a_byte_is_read():
    """/dev/zero never ends: reading it whole filled the memory until the kernel killed gonio."""
    for reader in (read_merl, read_tensor, lambda p: read_named_file(p, 1 << 20)):
        with pytest.raises(ValueError, match="is not a regular file"):
            reader("/dev/zero")


@pytest.mark.parametrize("argv", [
    ["plan", "--grid", "iso:step=45", "--config", "/dev/zero"],
    ["simulate", "merl:/dev/zero", "--grid", "iso:step=45", "--quiet"],
    ["simulate", "bsdf:/dev/zero", "--grid", "iso:step=45", "--quiet"],
])
def test_the_cli_says_so_in_one_line_and_writes_nothing(tmp_path, capsys, argv):
    out = tmp_path / "run"
    args = [*argv, "--out", str(out)] if argv[0] == "simulate" else argv
    try:
        code = main(args)
    except SystemExit as exit_:
        code = exit_.code
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "/dev/zero" in err and "is not a regular file" in err, err
    assert not out.exists()
