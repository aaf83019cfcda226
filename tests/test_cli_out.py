"""--out as a user types it: never empty, never silently replacing a file; and the other places where a
command used to accept what it should refuse (a fit value beyond the fit's bounds, a busy port)."""

from __future__ import annotations

import socket
import subprocess
import sys

import pytest
from cli_helpers import one_clear_line as _one_line

from gonio.cli import main


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    folder = tmp_path_factory.mktemp("out") / "lambert"
    argv = ["simulate", "lambert:albedo=0.5", "--grid", "iso:step=45", "--out", str(folder), "--quiet"]
    assert main(argv) == 0
    return folder


def _files(folder):
    """What is in ``folder``, but the read-only journal's SQLite side files."""
    return sorted(p.name for p in folder.iterdir() if not p.name.endswith(("-shm", "-wal")))


@pytest.mark.parametrize("argv", [
    ["simulate", "lambert:albedo=0.5", "--grid", "iso:step=45", "--quiet", "--out", ""],
    ["simulate", "lambert:albedo=0.5", "--grid", "iso:step=45,order=fly", "--quiet", "--out", " "],
    ["run", "--config", "sim", "--material", "lambert:albedo=0.5", "--sample", "s", "--grid", "iso:step=45",
     "--quiet", "--out", ""],
    ["export", "{c}", "--format", "csv", "--out", ""],
    ["export", "{c}", "--format", "radiance", "--out", ""],
    ["fit", "{c}", "--model", "lambert", "--out", ""],
    ["plot", "{c}", "--kind", "polar", "--out", ""],
    ["report", "{c}", "--out", ""],
])
def test_an_empty_out_is_one_line_exit_2_and_nothing_is_written(argv, campaign, tmp_path, monkeypatch,
                                                                 capsys):
    monkeypatch.chdir(tmp_path)   # an empty --out used to write the campaign into the current folder
    argv = [str(campaign) if a == "{c}" else a for a in argv]
    before = _files(campaign)
    assert main(argv) == 2
    _one_line(capsys, "--out", "empty")
    assert _files(tmp_path) == [] and _files(campaign) == before


@pytest.mark.parametrize("argv, name", [
    (["export", "{c}", "--format", "csv"], "x.csv"),
    (["export", "{c}", "--format", "radiance"], "pab"),
    (["fit", "{c}", "--model", "lambert", "--quiet"], "fit.json"),
    (["plot", "{c}", "--kind", "albedo"], "a.png"),
    (["report", "{c}", "--models", "lambert"], "r.html"),
])
def test_an_existing_out_is_replaced_only_with_force(argv, name, campaign, tmp_path, capsys):
    out = tmp_path / name
    if name == "pab":
        out.mkdir()
        (out / "keep.txt").write_text("mine")
    else:
        out.write_text("mine")
    argv = [str(campaign) if a == "{c}" else a for a in argv] + ["--out", str(out)]
    assert main(argv) == 2
    _one_line(capsys, "--out", str(out), "exists", "--force")
    assert (out / "keep.txt" if name == "pab" else out).read_text() == "mine"
    assert main([*argv, "--force"]) == 0
    capsys.readouterr()
    if name != "pab":
        assert out.read_text() != "mine" if name != "a.png" else out.read_bytes()[:4] == b"\x89PNG"


@pytest.mark.parametrize("model, says", [
    ("ggx:alpha=5", "alpha=5 is outside the range the fit uses for alpha, [0.001, 2]"),
    ("ward:alpha=3", "alpha=3 is outside the range the fit uses for alpha, [0.001, 1]"),
    ("cook-torrance:fresnel=conductor,eta=20", "eta=20 is outside"),
    ("phong:ke=20000", "ke=20000 is outside"),
])
def test_a_fixed_fit_value_beyond_the_fit_bounds_is_refused(model, says, campaign, capsys):
    assert main(["fit", str(campaign), "--model", model]) == 2
    _one_line(capsys, f"model '{model}'", says)


def test_fixed_fit_values_within_the_bounds_are_held(campaign, capsys):
    assert main(["fit", str(campaign), "--model", "ggx:alpha=0.2", "--quiet"]) == 0
    assert "alpha=0.2," in capsys.readouterr().out


def test_serve_on_a_busy_port_leaves_nothing_in_the_data_folder(tmp_path):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        data = tmp_path / "data"
        argv = [sys.executable, "-m", "gonio.cli", "serve", "--port", str(port), "--data", str(data)]
        r = subprocess.run(argv, capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r.stderr
    assert "--port" in r.stderr and "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert not data.exists()   # no daemon.lock, no folder: nothing of a daemon that never ran
