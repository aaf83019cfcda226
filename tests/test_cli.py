"""The `gonio` command as a user runs it (in-process through main(), and once as a real process)."""

import json
import subprocess
import sys

import h5py
import numpy as np
import pytest

from gonio.cli import main


def test_plan_json_has_counts_and_durations(capsys):
    assert main(["plan", "--grid", "iso:step=30", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["poses"] == out["counts"]["feasible"] > 0
    assert out["lower_bound_s"] <= out["estimated_s"]
    assert out["symmetries"]["reciprocity"] is True


def test_plan_report_names_every_stage(capsys):
    assert main(["plan", "--grid", "iso:step=30,mirror=true"]) == 0
    text = capsys.readouterr().out
    for word in ("reciprocity", "mirror", "occlusion", "lower bound"):
        assert word in text


@pytest.mark.parametrize("argv, message", [
    (["plan", "--grid", "iso:step=0"], "option 'step' must be > 0"),
    (["plan", "--grid", "polar:step=5"], "iso"),
    (["plan", "--grid", "iso:step=5,colour=red"], "colour"),
    (["simulate", "lambert:albedo=1.5", "--grid", "iso:step=45", "--out", "X"], "albedo"),
    (["simulate", "velvet:x=1", "--grid", "iso:step=45", "--out", "X"], "lambert"),
])
def test_bad_input_is_one_clear_line(argv, message, capsys, tmp_path):
    argv = [str(tmp_path / a) if a == "X" else a for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert not (tmp_path / "X").exists()  # nothing half-made


def test_unknown_config_key_names_the_file_and_key(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text(open("config/sim.toml").read().replace("[light]", "[light]\nwattage = 3"))
    assert main(["plan", "--grid", "iso:step=30", "--config", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "light.wattage: unknown key" in err and str(bad) in err


def test_clearance_that_makes_everything_infeasible_names_the_field(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text(open("config/sim.toml").read().replace("clearance_deg = 5.0", "clearance_deg = 89.0"))
    assert main(["plan", "--grid", "iso:step=30", "--config", str(bad)]) == 2
    assert "clearance_deg" in capsys.readouterr().err


class Crash(BaseException):
    pass


def test_simulate_resumes_a_crashed_campaign_and_refuses_another(tmp_path, capsys):
    from gonio.campaign import create_campaign, open_campaign, run_campaign
    from gonio.config import load_config
    from gonio.wiring import build_gantry

    out = tmp_path / "run"
    create_campaign(out, load_config(), grid="iso:step=45", material="lambert:albedo=0.5").close()

    def crash(n):
        if n == 5:  # the start event, then four committed steps
            raise Crash

    c = open_campaign(out, write_hook=crash)
    with pytest.raises(Crash):
        run_campaign(c, build_gantry(c.cfg, "lambert:albedo=0.5"))
    n_steps = c.journal.step_count()
    c.close()  # the process died: its connection and its lock on the folder go with it
    c = open_campaign(out, readonly=True)
    done_before = c.journal.done_steps().size
    c.close()
    assert 0 < done_before < n_steps
    args = ["simulate", "lambert:albedo=0.5", "--grid", "iso:step=45", "--out", str(out), "--quiet"]
    assert main(args) == 0
    err = capsys.readouterr().err
    assert f"resuming the campaign in {out} at step {done_before}" in err
    assert "median relative error" in err
    with h5py.File(out / "brdf.h5") as f:
        np.testing.assert_allclose(f["samples/value"][()], 0.5 / np.pi, rtol=0.01)
    other = ["simulate", "lambert:albedo=0.7", "--grid", "iso:step=45", "--out", str(out), "--quiet"]
    assert main(other) == 2
    assert "holds another campaign" in capsys.readouterr().err


def test_console_script_runs_as_a_process(tmp_path):
    r = subprocess.run([sys.executable, "-m", "gonio.cli", "plan", "--grid", "full:step=60", "--json"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["symmetries"]["isotropy"] is False
