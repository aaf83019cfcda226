"""gonio run (and gantry, serve) on devices that cannot be reached: a shipped emulated-* config used
without `gonio emulate --write-config`, or a port that does not open. One line saying what to do, before
anything is planned, and nothing written: no campaign.sqlite, no campaign.lock, nothing for `gonio
status` to call a "created" campaign."""

from __future__ import annotations

import subprocess
import sys
import tomllib

import pytest
from cli_helpers import one_clear_line

import gonio.campaign
import gonio.plan
from gonio.cli import main
from gonio.config import resolve_config


@pytest.fixture
def no_planning(monkeypatch):
    def refuse(*a, **k):
        raise AssertionError("planned although the gantry cannot be reached")

    monkeypatch.setattr(gonio.plan, "build_plan", refuse)
    monkeypatch.setattr(gonio.campaign, "build_plan", refuse, raising=False)


@pytest.mark.parametrize("name", ["emulated-two-arm-dynamixel", "emulated-sample-stage-modbus"])
def test_a_shipped_emulated_config_says_to_start_gonio_emulate(name, tmp_path, capsys, no_planning):
    out = tmp_path / "run"
    argv = ["run", "--config", name, "--grid", "iso:step=30", "--out", str(out), "--sample", "felt"]
    assert main(argv) == 2
    one_clear_line(capsys, f"gonio emulate --config {name} --write-config emu.toml", "--config emu.toml")
    assert list(tmp_path.iterdir()) == []
    assert main(["gantry", "status", "--config", name]) == 2
    one_clear_line(capsys, f"gonio emulate --config {name}")


def test_serve_with_an_emulated_config_says_so_and_writes_nothing(tmp_path):
    data = tmp_path / "data"
    r = subprocess.run([sys.executable, "-m", "gonio.cli", "serve", "--config", "emulated-two-arm-dynamixel",
                        "--data", str(data), "--port", "0"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "gonio emulate --config emulated-two-arm-dynamixel" in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and not data.exists()


def test_a_port_that_does_not_open_is_one_line_exit_1_before_planning(tmp_path, capsys, no_planning):
    text = resolve_config("two-arm-dynamixel").read_text()
    cfg = tomllib.loads(text)
    port = cfg["buses"]["arm"]["port"]
    missing = tmp_path / "ttyUSB-unplugged"
    config = tmp_path / "gantry.toml"
    config.write_text(text.replace(port, str(missing)))
    out = tmp_path / "run"
    argv = ["run", "--config", str(config), "--grid", "iso:step=30", "--out", str(out), "--sample", "felt"]
    assert main(argv) == 1
    one_clear_line(capsys, "cannot open port", str(missing), "nothing was written")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["gantry.toml"]
