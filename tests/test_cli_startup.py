"""Fast start: ``gonio --version`` and ``gonio <command> --help`` import none of the heavy libraries a
command uses, and a command that works imports what its work needs, not what the others' does (a
behavioural check: which modules are loaded, not how long it takes; the figures are
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


# -- commands that do their work import what their work needs, not every other command's libraries ---
#: What each command must not import (checked on a finished campaign); the libraries a command does need
#: (pydantic for a config, h5py for brdf.h5, drjit to simulate) are left out of its row. Off a terminal
#: (this probe's stderr is a pipe) no command needs rich to write its lines (gonio.cli.common.Out).
NOT_NEEDED = {
    "status": ("rich", "scipy", "drjit", "matplotlib", "h5py", "pydantic", "gonio.config",
               "gonio.plan.build", "fastapi", "httpx", "skimage"),
    "export": ("rich", "scipy", "drjit", "matplotlib", "pydantic", "gonio.config", "gonio.plan.build",
               "fastapi", "skimage"),
    "plan": ("rich", "drjit", "matplotlib", "h5py", "fastapi", "skimage", "gonio.sim.materials",
             "scipy.spatial"),
    # A plan of a few poses finds neighbours without a k-d tree (gonio.motion.nearest).
    "simulate": ("rich", "matplotlib", "fastapi", "uvicorn", "httpx", "skimage", "scipy.ndimage",
                 "scipy.optimize", "scipy.spatial", "gonio.export", "gonio.fit", "gonio.daemon.app"),
    # The simulated camera erodes its sample region without scikit-image's morphology (and the
    # scipy.spatial that imports): gonio.frames.erode_disk.
    "simulate --detector camera": ("matplotlib", "fastapi", "skimage", "scipy.spatial", "scipy.ndimage",
                                   "gonio.export", "gonio.fit", "gonio.daemon.app"),
    # gonio run on a simulated gantry: what simulate needs, none of the hardware drivers' libraries.
    "run": ("rich", "matplotlib", "fastapi", "uvicorn", "httpx", "skimage", "scipy.ndimage", "scipy.optimize",
            "scipy.spatial", "gonio.export", "gonio.fit", "gonio.daemon.app", "pymodbus", "serial",
            "dynamixel_sdk"),
}


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    from gonio.cli import main

    folder = tmp_path_factory.mktemp("startup") / "c"
    argv = ["simulate", "lambert:albedo=0.5", "--grid", "iso:step=45", "--quiet", "--out", str(folder)]
    assert main(argv) == 0
    return folder


@pytest.mark.parametrize("command", sorted(NOT_NEEDED))
def test_a_command_imports_only_what_its_work_needs(command, finished, tmp_path):
    argv = {"status": ["status", str(finished)],
            "export": ["export", str(finished), "--format", "csv", "--out", str(tmp_path / "c.csv")],
            "plan": ["plan", "--grid", "iso:step=45"],
            "simulate": ["simulate", "lambert:albedo=0.5", "--grid", "iso:step=45", "--quiet", "--out",
                         str(tmp_path / "s")],
            "simulate --detector camera": ["simulate", "lambert:albedo=0.5", "--grid", "iso:step=45",
                                           "--detector", "camera", "--quiet", "--out", str(tmp_path / "cam")],
            "run": ["run", "--config", "sim", "--material", "lambert:albedo=0.5", "--sample", "felt",
                    "--grid", "iso:step=45", "--quiet", "--out", str(tmp_path / "r")]}[command]
    code, modules = _loaded(*argv)
    assert code == 0
    loaded = sorted(m for m in NOT_NEEDED[command] if m in modules)
    assert loaded == [], f"gonio {command} imported {loaded}"
    if command == "simulate --detector camera":
        assert "gonio.frames" in modules and (tmp_path / "cam" / "brdf.h5").is_file()   # it ran the camera


def test_a_fly_campaign_is_planned_once_and_rebuilt_once_on_resume(tmp_path, monkeypatch):
    """A fly campaign created by this process runs the fly plan it was created from (the planner runs
    once, not again to rebuild it from the journal just written); a resumed one rebuilds its plan from
    the journal once (and checks it against the journal's steps)."""
    import gonio.fly.plans as plans
    from gonio.cli import main

    built = []
    real = plans.build_plan
    monkeypatch.setattr(plans, "build_plan", lambda *a, **k: built.append(a[0]) or real(*a, **k))
    out = tmp_path / "fly"
    argv = ["simulate", "lambert:albedo=0.5", "--grid", "iso:step=45,order=fly", "--quiet", "--out", str(out)]
    assert main(argv) == 0
    assert built == ["iso:step=45,order=fly"]
    (out / "brdf.h5").unlink()    # finished but for its brdf.h5: the same command resumes it
    built.clear()
    assert main(argv) == 0
    assert len(built) == 1 and (out / "brdf.h5").exists()
