"""Fast start: ``gonio --version`` and ``gonio <command> --help`` import none of the heavy libraries a
command uses (a behavioural check: which modules are loaded, not how long it takes; the figures are
tools/bench_startup.py's, in BENCHMARKS.md)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

#: Libraries that cost tens to hundreds of ms of CPU each to import; no command's help needs one.
HEAVY = ("numpy", "scipy", "pydantic", "drjit", "fastapi", "uvicorn", "httpx", "matplotlib", "h5py",
         "pymodbus", "serial", "dynamixel_sdk", "rich", "gonio.config", "gonio.plan.grids")

PROBE = """
import json, sys
from gonio.cli import main
try:
    code = main(sys.argv[1:])
except SystemExit as exit_:
    code = exit_.code
print(json.dumps({"code": code, "modules": sorted(sys.modules)}))
"""


def _loaded(*argv: str) -> tuple[int, set[str]]:
    out = subprocess.run([sys.executable, "-c", PROBE, *argv], capture_output=True, text=True, check=True,
                         timeout=60)
    result = json.loads(out.stdout.strip().splitlines()[-1])
    return result["code"], set(result["modules"])


def _commands() -> list[str]:
    from gonio.cli import build_parser

    return sorted(build_parser().commands)


@pytest.mark.parametrize("argv", [("--version",), ("--help",)] + [(c, "--help") for c in _commands()],
                         ids=lambda a: " ".join(a))
def test_version_and_help_import_no_heavy_library(argv):
    code, modules = _loaded(*argv)
    assert code == 0
    heavy = sorted(m for m in HEAVY if m in modules)
    assert heavy == [], f"gonio {' '.join(argv)} imported {heavy}"


def test_the_probe_sees_what_a_command_imports():
    """The check can fail: a command that runs (gonio config list) imports pydantic through the config."""
    code, modules = _loaded("config", "list")
    assert code == 0 and "pydantic" in modules and "gonio.config" in modules
