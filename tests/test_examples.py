"""The scripts of examples/ run as a lab would start them (a fresh folder, `python examples/NAME.py`) and
leave what their docstrings say."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
pytestmark = pytest.mark.slow


def _run(name: str, cwd: Path, *args: str) -> str:
    r = subprocess.run([sys.executable, str(ROOT / "examples" / name), *args], cwd=cwd, capture_output=True,
                       text=True, timeout=600)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-4000:]
    assert "Traceback" not in r.stderr
    return r.stdout


def _image(path: Path) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(path).convert("RGB"), float)


def test_render_sphere_renders_a_gold_sphere_from_the_export(tmp_path):
    pytest.importorskip("mitsuba")
    out = _run("render_sphere.py", tmp_path, "sphere")
    folder = tmp_path / "sphere"
    assert "bsdf: " in out and (folder / "gold.bsdf").is_file() and (folder / "sphere.exr").is_file()
    img = _image(folder / "sphere.png")
    centre, corner = img[48:80, 48:80].mean(axis=(0, 1)), img[:8, :8].mean(axis=(0, 1))
    assert centre.sum() > corner.sum() + 60          # a lit sphere in front of a dim sky
    assert centre[0] > centre[2] * 1.3               # gold: more red than blue


def test_emulated_plot_measures_through_the_drivers_and_draws(tmp_path):
    out = _run("emulated_plot.py", tmp_path)
    folder = tmp_path / "runs" / "emulated-plot"
    assert "campaign done" in out
    with h5py.File(folder / "brdf.h5") as f:
        assert f.attrs["sample"] == "gold foil" and f["samples/value"].shape == (26, 1)
    for kind in ("polar", "albedo"):
        assert _image(folder / f"{kind}.png").std() > 10


def test_daemon_events_follows_a_campaign_to_its_end_and_fetches_it(tmp_path):
    out = _run("daemon_events.py", tmp_path)
    assert "submitted c00001" in out and "30/30" in out and "c00001: done" in out
    with h5py.File(tmp_path / "runs" / "daemon-events" / "brdf.h5") as f:
        assert f["samples/value"].shape[0] == 26
