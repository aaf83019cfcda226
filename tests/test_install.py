"""A plain (non-editable) install works outside the source tree: the wheel carries the configs as package
data, so `gonio plan` and a small `gonio simulate` run from any folder."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest
from built_once import built_once

ROOT = Path(__file__).resolve().parent.parent
pytestmark = pytest.mark.slow


def _run(argv, **kw):
    r = subprocess.run(argv, capture_output=True, text=True, timeout=600, **kw)
    assert r.returncode == 0, f"{argv}: {r.stdout}\n{r.stderr}"
    return r


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """(the new environment, the folder of the build): built once per run (tests/built_once.py), whichever
    worker's tests ask first; the tests only read it."""
    return built_once(tmp_path_factory, "install", _build_and_install)


def _build_and_install(base: Path) -> tuple[Path, Path]:
    wheels = base / "wheels"
    # Built from a clean copy of the sources: setuptools reuses a build/ folder, whose stale files from an
    # earlier build (modules since moved, packages the list no longer names) would hide what the wheel lacks.
    src = base / "src"
    shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns(".git", ".venv", "build", "*.egg-info",
                                                             "__pycache__", "demo-out", "gonio-data"))
    # The build uses this environment's setuptools (no download); the wheel is what `pip install .` makes.
    # Verbose: setuptools' warnings about the package list are shown only then (pip -q hides them).
    build = _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-v", "-w",
                  str(wheels), str(src)])
    (base / "build.log").write_text(build.stdout + build.stderr)
    (wheel,) = wheels.glob("gonio-*.whl")
    venv = base / "venv"
    # Without a pip of its own (ensurepip installing one into it cost 4.4 s of CPU): this environment's
    # pip installs into it (--python), as the new environment's own would.
    _run([sys.executable, "-m", "venv", "--without-pip", str(venv)])
    py = venv / "bin" / "python"
    # gonio's dependencies come from this environment (a path, not its .pth files: the editable gonio of
    # the source tree stays out); gonio itself from the wheel, installed by pip into the new environment.
    where = "import sysconfig; print(sysconfig.get_paths()['purelib'])"
    site = Path(_run([str(py), "-c", where]).stdout.strip())
    # Every site-packages folder of this environment: a worktree's environment may borrow its packages
    # from another one through a .pth file of its own, which the new environment would not follow.
    deps = [sysconfig.get_paths()["purelib"]] + [p for p in sys.path if p.endswith("site-packages")]
    (site / "deps.pth").write_text("\n".join(dict.fromkeys(deps)) + "\n")
    _run([sys.executable, "-m", "pip", "--python", str(py), "install", "-q", "--no-deps", "--no-index",
          str(wheel)])
    return venv, base


@pytest.fixture(scope="module")
def wheel_build(installed):
    base = installed[1]
    (wheel,) = (base / "wheels").glob("gonio-*.whl")
    return wheel, (base / "build.log").read_text()


def test_the_wheel_build_warns_of_nothing_and_carries_every_data_file(wheel_build):
    """Data folders missing from the package list made setuptools print a screen of "Package would be
    ignored" warnings on every install; each data file of the source tree must be in the wheel."""
    import zipfile

    wheel, log = wheel_build
    assert "would be ignored" not in log and "SetuptoolsDeprecationWarning" not in log, log[-3000:]
    inside = set(zipfile.ZipFile(wheel).namelist())
    roots = {"gonio": ROOT / "gonio", "gonio/drivers": ROOT / "drivers", "gonio/sim": ROOT / "sim",
             "gonio/configs": ROOT / "config"}
    data = [(prefix, f.relative_to(folder)) for prefix, folder in roots.items() for f in folder.rglob("*")
            if f.is_file() and f.suffix not in (".py", ".pyc", ".md") and "__pycache__" not in f.parts]
    assert len(data) >= 16   # configs, Modbus profiles, spectral tables, the web view
    names = [f"{prefix}/{rel.as_posix()}" for prefix, rel in data]
    missing = [name for name in names if name not in inside]
    assert missing == []


#: What runs in one process of the new environment (each process pays gonio's start-up again; what is
#: tested is what the wheel installed): each argv of sys.argv[1] (JSON) through gonio.cli.main, then an
#: import of each module named in sys.argv[2] (JSON). Prints a JSON object: "commands", a list of
#: [exit code, stdout, stderr], one per argv, and "bad", the modules that failed to import from
#: site-packages, each "NAME: ERROR".
_IN_THE_WHEEL = """
import contextlib, importlib, io, json, sys
from gonio.cli import main
done = []
for argv in json.loads(sys.argv[1]):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(argv)
    done.append([rc, out.getvalue(), err.getvalue()])
bad = []
for n in json.loads(sys.argv[2]):
    try:
        m = importlib.import_module(n)
        assert 'site-packages' in (m.__file__ or ''), m.__file__
    except Exception as e:
        bad.append(f'{n}: {type(e).__name__}: {e}')
print(json.dumps({"commands": done, "bad": bad}))
"""

#: The commands run from the installed wheel, in one process (:data:`_IN_THE_WHEEL`).
COMMANDS = [
    ["config", "list"],
    ["plan", "--grid", "iso:step=30"],
    ["plan", "--grid", "full:step=60", "--config", "sample-stage"],
    # a config naming the SCPI instrument profiles: they ship as package data too
    ["plan", "--grid", "iso:step=60", "--config", "emulated-two-arm-scpi"],
    ["simulate", "lambert:albedo=0.5", "--grid", "iso:step=45", "--out", "run", "--quiet"]]


def _source_modules() -> list[str]:
    """Every module of the source tree, by the name the wheel installs it under (drivers/ and sim/ are
    mapped into gonio)."""
    roots = {"gonio": ROOT / "gonio", "gonio.drivers": ROOT / "drivers", "gonio.sim": ROOT / "sim"}
    names = set()
    for prefix, folder in roots.items():
        for f in folder.rglob("*.py"):
            parts = f.relative_to(folder).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            if parts[-1:] == ("__main__",):
                continue
            names.add(".".join((prefix, *parts)))
    return sorted(names)


@pytest.fixture(scope="module")
def in_the_wheel(installed, tmp_path_factory):
    """The new environment run outside the source tree, from a folder of this worker's own: (venv, cwd, env,
    what :data:`_IN_THE_WHEEL` printed for :data:`COMMANDS` and every module of the source tree)."""
    venv, cwd = installed[0], tmp_path_factory.mktemp("elsewhere")
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    r = _run([str(venv / "bin" / "python"), "-c", _IN_THE_WHEEL, json.dumps(COMMANDS),
              json.dumps(_source_modules())], cwd=cwd, env=env)
    return venv, cwd, env, json.loads(r.stdout)


def test_wheel_installs_gonio_with_its_configs_outside_the_source_tree(in_the_wheel):
    venv, cwd, env, ran = in_the_wheel
    code = "import gonio, gonio.config as c; print(gonio.__file__); print(c.DEFAULT_CONFIG)"
    r = _run([str(venv / "bin" / "python"), "-c", code], cwd=cwd, env=env)
    module, default = r.stdout.split()
    assert Path(module).is_relative_to(venv) and Path(default).is_relative_to(venv)
    assert not Path(module).is_relative_to(ROOT)
    # The console script, then the commands through gonio.cli.main in one process of the new environment.
    assert "gonio 0." in _run([str(venv / "bin" / "gonio"), "--version"], cwd=cwd, env=env).stdout
    for argv, (rc, out, err) in zip(COMMANDS, ran["commands"], strict=True):
        assert rc == 0, f"gonio {' '.join(argv)}: {out}\n{err}"
    (config, plan, *_, simulate) = [(out, err) for _, out, err in ran["commands"]]
    assert "sample-stage" in config[0] and "lower bound" in plan[0]
    assert (cwd / "run" / "brdf.h5").is_file() and "median relative error" in simulate[1]


def test_every_module_of_the_source_tree_is_in_the_wheel_and_imports(in_the_wheel):
    """The wheel's package list is written by hand (drivers/ and sim/ are mapped into gonio): a package
    left out of it installs without complaint and fails only when its command runs."""
    venv, cwd, env, ran = in_the_wheel
    assert ran["bad"] == []
    assert len(_source_modules()) > 80
    r = _run([str(venv / "bin" / "gonio"), "fit", "--help"], cwd=cwd, env=env)
    assert "--model" in r.stdout
