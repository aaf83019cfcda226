"""The four extensions of docs/EXTENDING.md, each a toy plugin in ``tests/plugins/<name>/`` within its file
budget, loaded the way a lab loads one (``GONIO_PLUGINS``, in a fresh process: a driver's config model
joins the config's unions when gonio.config is first imported) and checked by what it does: the files
it writes read back, the registers it sets read by another Modbus client, the readings it returns, the
BRDF a campaign on its gantry measures."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from gonio.cli import main
from gonio.config import CONFIG_DIR
from gonio.dataset import read_brdf
from gonio.registries import EXPORT_FORMATS

PLUGINS = Path(__file__).parent / "plugins"
#: Files each kind of extension may take (its test not counted): docs/EXTENDING.md.
BUDGETS = {"toy_format": 1, "toy_family": 3, "toy_detector": 3, "toy_design": 3}


def with_plugin(plugin: str, *argv: str, code: str | None = None, cwd=None) -> subprocess.CompletedProcess:
    """``gonio ARGV`` (or ``python -c CODE``) in a fresh process with ``plugin`` named by GONIO_PLUGINS."""
    path = os.pathsep.join(filter(None, [str(PLUGINS / plugin), os.environ.get("PYTHONPATH")]))
    env = {**os.environ, "GONIO_PLUGINS": plugin, "PYTHONPATH": path}
    cmd = [sys.executable, "-c", textwrap.dedent(code)] if code else \
        [sys.executable, "-m", "gonio.cli", *argv]
    return subprocess.run(cmd, env=env, cwd=cwd, capture_output=True, text=True, timeout=180)


def test_each_toy_is_within_its_file_budget():
    for plugin, budget in BUDGETS.items():
        files = sorted(p.name for p in (PLUGINS / plugin).iterdir() if p.name != "__pycache__")
        assert 1 <= len(files) <= budget, (plugin, files)


@pytest.mark.slow
def test_an_export_format_is_one_file(tmp_path, capsys):
    """``jsonl`` is listed by ``gonio export --help``, accepted by ``--export`` and written into the
    campaign folder under its registered name, holding every sample of brdf.h5."""
    r = with_plugin("toy_format", "export", "--help")
    assert r.returncode == 0 and "jsonl" in r.stdout and "JSON lines" in r.stdout
    out = tmp_path / "c"
    r = with_plugin("toy_format", "simulate", "lambert:albedo=0.5", "--grid", "iso:step=45", "--out",
                    str(out), "--quiet", "--export", "jsonl,csv")
    assert r.returncode == 0, r.stderr
    rows = [json.loads(line) for line in (out / "brdf.samples.jsonl").read_text().splitlines()]
    data = read_brdf(out / "brdf.h5")
    assert len(rows) == len(data.theta_i) > 0
    for key in ("theta_i", "phi_i", "theta_o", "phi_o"):
        assert [row[key] for row in rows] == np.asarray(getattr(data, key), float).tolist()
    assert np.array_equal(np.array([row["f_r"] for row in rows]), np.asarray(data.value, float))
    # Without the plugin (this process loads none) the name is refused, naming the formats there are.
    assert "jsonl" not in EXPORT_FORMATS
    capsys.readouterr()
    assert main(["simulate", "lambert:albedo=0.5", "--grid", "iso:step=45", "--out", str(tmp_path / "d"),
                 "--export", "jsonl"]) == 2
    err = capsys.readouterr().err
    assert "jsonl" in err and "csv" in err
    assert not (tmp_path / "d").exists()


MODBUS = """
    import json
    from pymodbus.client import ModbusTcpClient
    from gonio.clock import WallClock
    from gonio.device_config import BuildContext
    from gonio.registries import AXIS_DRIVERS, BUS_DRIVERS
    from gonio.sim.emulators.modbus import ModbusMotorEmulator

    emu = ModbusMotorEmulator("toy_enable")
    host, port = emu.start_tcp()
    probe = ModbusTcpClient(host, port=port)
    try:
        bus = BUS_DRIVERS.load("modbus")(driver="modbus", url=f"tcp://{host}:{port}")
        cfg = AXIS_DRIVERS.load("modbus")(driver="modbus", bus="b", device_id=1, profile="toy_enable",
                                          min_deg=-90, max_deg=90, max_velocity_deg_s=10,
                                          max_accel_deg_s2=20)
        axis = cfg.build("x", BuildContext(cfg=None, clock=WallClock(), buses={"b": bus.open("b")}))
        probe.connect()
        servo = lambda: probe.read_holding_registers(0x0115, count=1, device_id=1).registers[0]
        seen = {"class": type(axis).__name__, "before": servo()}
        axis.connect()
        seen["connected"] = servo()
        seen["position_deg"] = axis.position_deg()
        axis.close()
        seen["closed"] = servo()
        print(json.dumps(seen))
    finally:
        probe.close()
        emu.stop()
"""


def test_a_modbus_family_with_its_own_behaviour():
    """A profile named by the family is driven by the family's axis class, whose servo-enable register
    another Modbus client reads set at connect and cleared at close."""
    r = with_plugin("toy_family", code=MODBUS)
    assert r.returncode == 0, r.stderr
    seen = json.loads(r.stdout.strip().splitlines()[-1])
    assert seen == {"class": "ToyEnableAxis", "before": 0, "connected": 1, "position_deg": 0.0, "closed": 0}


DETECTOR = """
    import json, tomllib
    from gonio.config import CONFIG_DIR, parse_config
    from gonio.wiring import build_gantry

    data = tomllib.loads((CONFIG_DIR / "sim.toml").read_text())
    data["detector"] = {"driver": "toy-counter", "channels": ["N"], "rate_hz": 2000.0, "dark_hz": 10.0}
    data["axes"]["changer"] = {"min_deg": 0, "max_deg": 90, "max_velocity_deg_s": 900,
                               "max_accel_deg_s2": 9000}
    data["target"] = {"axis": "changer", "reference_deg": 90}
    gantry = build_gantry(parse_config(data))
    gantry.connect()
    seen = {"kind": gantry.detector.describe()["model"]}
    gantry.light.set_on(True)
    seen["lit"] = gantry.detector.measure(0.5).signal.tolist()
    gantry.light.set_on(False)
    seen["dark"] = gantry.detector.measure(0.5).signal.tolist()
    gantry.close()
    print(json.dumps(seen))
"""


def test_a_detector_is_its_config_model_and_its_device(tmp_path):
    r = with_plugin("toy_detector", code=DETECTOR)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout.strip().splitlines()[-1]) == {"kind": "toy counter", "lit": [1000.0],
                                                             "dark": [5.0]}
    # Its own settings are checked as any driver's: one line naming the field, exit 2, nothing planned.
    sim = (CONFIG_DIR / "sim.toml").read_text()
    cfg = tmp_path / "bad.toml"
    cfg.write_text(sim[:sim.index("\n[detector]")]
                   + '\n[detector]\ndriver = "toy-counter"\nchannels = ["N"]\nrate_hz = 5.0\ndark_hz = 8.0\n'
                   + '\n[axes.changer]\nmin_deg = 0.0\nmax_deg = 90.0\nmax_velocity_deg_s = 9.0\n'
                   + 'max_accel_deg_s2 = 9.0\n\n[target]\naxis = "changer"\n')
    r = with_plugin("toy_detector", "plan", "--config", str(cfg), "--grid", "iso:step=30")
    assert (r.returncode, r.stdout) == (2, "")
    assert r.stderr.strip().splitlines() == [f"gonio plan: {cfg}: detector: dark_hz: must be below rate_hz "
                                             "(5), got 8"]


@pytest.mark.slow
def test_a_gantry_design_measures_what_the_material_is(tmp_path, capsys):
    """A campaign on the toy design's simulated gantry measures the Lambertian it renders: its inverse and
    forward kinematics agree with the sample's frame."""
    config = PLUGINS / "toy_design" / "toy-spherical.toml"
    r = with_plugin("toy_design", "simulate", "lambert:albedo=0.5", "--config", str(config), "--grid",
                    "iso:step=30", "--out", str(tmp_path / "c"), "--quiet")
    assert r.returncode == 0, r.stderr
    data = read_brdf(tmp_path / "c" / "brdf.h5")
    assert len(data.theta_i) == 26
    assert np.allclose(data.value, 0.5 / np.pi, rtol=2e-3)
    # A script that imports gonio.config first loads the plugin while the config's models are built.
    r = with_plugin("toy_design", code=f"from gonio.config import load_config; "
                                      f"print(*load_config({str(config)!r}).axis_names)")
    assert (r.returncode, r.stdout) == (0, "light_ring light_polar detector_ring detector_polar\n"), r.stderr
    # Without the plugin (this process loads none) the design is refused, naming the designs there are.
    capsys.readouterr()
    assert main(["plan", "--config", str(config), "--grid", "iso:step=30"]) == 2
    assert ("kinematics.design: 'toy-spherical' is not a gantry design; allowed: two-arm, sample-stage"
            in capsys.readouterr().err)


def test_extending_shows_the_toys_as_they_are():
    """docs/EXTENDING.md shows each toy's files whole: a block that opens with ``# tests/plugins/PATH``
    is that file, and every toy file is shown."""
    import re

    doc = (Path(__file__).parent.parent / "docs" / "EXTENDING.md").read_text()
    shown = {m.group(2): m.group(3) for m in
             re.finditer(r"^```(py|toml)\n# tests/plugins/(\S+)\n(.*?)^```$", doc, re.S | re.M)}
    files = {str(p.relative_to(PLUGINS)): p.read_text() for p in sorted(PLUGINS.rglob("*"))
             if p.is_file() and "__pycache__" not in p.parts}
    assert shown == files
