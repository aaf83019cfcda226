"""The set-up behind `make demo` and `make test` (tools/setup.sh through the Makefile), run with stand-ins
for python3, apt-get and ldconfig that record what they are asked: `make demo` installs gonio with its
runtime dependencies only; the development extras and Debian's chromium come with `make test`."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

# python3 -m venv DIR makes DIR/bin/python, a stand-in that logs its arguments (pip installs included).
PYTHON3 = """#!/bin/sh
if [ "$1" = "-m" ] && [ "$2" = "venv" ]; then
  mkdir -p "$3/bin"
  printf '#!/bin/sh\\necho "python $*" >> "$LOG"\\n' > "$3/bin/python"
  printf '[ "$1 $2" = "-m uv" ] && [ -n "$UV_FAILS" ] && exit 1\\nexit 0\\n' >> "$3/bin/python"
  chmod +x "$3/bin/python"
  exit 0
fi
exit 1
"""
LOGGER = '#!/bin/sh\necho "{name} $*" >> "$LOG"\nexit 0\n'


@pytest.fixture
def tree(tmp_path):
    for name in ("Makefile", "pyproject.toml", "tools/setup.sh"):
        (tmp_path / name).parent.mkdir(exist_ok=True)
        shutil.copy2(ROOT / name, tmp_path / name)
    stubs = tmp_path / "stubs"
    stubs.mkdir()
    (stubs / "python3").write_text(PYTHON3)
    (stubs / "ldconfig").write_text("#!/bin/sh\nexit 0\n")
    for name in ("apt-get", "sudo"):
        (stubs / name).write_text(LOGGER.format(name=name))
    for f in stubs.iterdir():
        f.chmod(0o755)
    # chromium is found only through PATH: a PATH of the stand-ins and the basic tools hides a real one.
    tools = tmp_path / "bin"
    tools.mkdir()
    for name in ("bash", "sh", "make", "grep", "ls", "touch", "id", "mkdir", "chmod", "cat", "printf"):
        found = shutil.which(name)
        if found:
            (tools / name).symlink_to(found)
    env = {"PATH": f"{stubs}:{tools}", "LOG": str(tmp_path / "log"), "HOME": str(tmp_path)}
    return tmp_path, env


def _make(tree, target):
    folder, env = tree
    r = subprocess.run(["make", target], cwd=folder, env=env, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stdout + r.stderr
    log = folder / "log"
    return (log.read_text() if log.exists() else ""), r.stdout + r.stderr


def test_make_demo_installs_the_runtime_dependencies_only(tree):
    log, out = _make(tree, ".venv/.runtime-stamp")
    pip = [line for line in log.splitlines() if " pip install" in line]
    # uv installs (pip fetches it), as pip would: editable, the runtime dependencies only
    assert pip == ["python -m pip install -q uv",
                   "python -m uv pip install -q --python .venv/bin/python -e ."], log
    assert "chromium" not in log and "[dev]" not in log
    assert "warning" not in out.lower()


def test_where_uv_fails_pip_installs_as_before(tree):
    folder, env = tree
    log, out = _make((folder, {**env, "UV_FAILS": "1"}), ".venv/.runtime-stamp")
    pip = [line for line in log.splitlines() if " pip install" in line]
    assert pip[-1] == "python -m pip install -q --no-compile -e .", log
    assert "uv could not install; pip installs instead" in out
    (folder / "log").unlink()
    (folder / ".venv" / ".runtime-stamp").unlink()
    log, _ = _make((folder, {**env, "GONIO_NO_UV": "1"}), ".venv/.runtime-stamp")
    assert [line for line in log.splitlines() if " pip install" in line] == \
        ["python -m pip install -q --no-compile -e ."], log


def test_make_test_adds_the_development_extras_and_chromium(tree):
    log, _ = _make(tree, ".venv/.dev-stamp")
    assert "python -m uv pip install -q --python .venv/bin/python -e .[dev]" in log.splitlines()
    if os.getuid() == 0:
        assert "apt-get install -y -q chromium" in log
    # and a `make demo` afterwards installs nothing more
    folder, _ = tree
    (folder / "log").unlink()
    log, _ = _make(tree, ".venv/.runtime-stamp")
    assert log == ""
