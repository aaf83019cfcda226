"""The `gonio` command as a user runs it (in-process through main(), and once as a real process)."""

import io
import json
import os
import re
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
from cli_helpers import one_clear_line as _one_clear_line

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
    # one exposure per sweeping axis: it read "exposure 250 ms, 333 ms", as if a reading took both
    assert re.search(r"readings \(exposure \d+ ms or \d+ ms, blur up to", text), text


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


@pytest.mark.parametrize("argv", [
    ["plan", "--grid", "iso:stp=30"],
    ["simulate", "lambert:albedo=0.5", "--grid", "iso:stp=30", "--out", "X"],
    ["run", "--config", "sim", "--material", "lambert:albedo=0.5", "--sample", "s", "--grid", "iso:stp=30",
     "--out", "X"],
])
def test_a_mistake_in_the_grid_names_the_grid_argument(argv, capsys, tmp_path):
    """A grid typo's line names --grid, as a material's names MATERIAL and a path's --out (it named the
    grid's kind only: 'gonio plan: grid 'iso': unknown option 'stp'')."""
    argv = [str(tmp_path / a) if a == "X" else a for a in argv]
    assert main(argv) == 2
    _one_clear_line(capsys, f"gonio {argv[0]}: --grid: grid 'iso': unknown option 'stp'; allowed: step")
    assert not (tmp_path / "X").exists()


@pytest.mark.parametrize("grid, says", [
    ("adaptive:poses=2", "grid 'adaptive': option 'poses' must be at least the pilot's 3 poses"),
    ("iso:step=0.001", "grid 'iso': 1,152,000,000,160,001 poses exceed the 3,000,000 a plan can hold"),
])
def test_a_grid_the_planner_refuses_names_the_grid_argument_in_gonio_plan_too(grid, says, capsys):
    """What only the planner finds (an adaptive budget below its pilot, a lattice past the pose limit) is
    the grid's fault in `gonio plan` as in `gonio simulate`, which says --grid."""
    assert main(["plan", "--grid", grid]) == 2
    _one_clear_line(capsys, f"gonio plan: --grid: {says}")


@pytest.mark.parametrize("argv, message", [
    (["simulate", "lambert:albedo=0.5", "--grid", "iso:step=45"],
     "gonio simulate: the following arguments are required: --out; `gonio simulate --help`"),
    (["plot", "X", "--out", "p.png"], "gonio plot: the following arguments are required: --kind"),
    (["simulate", "lambert:albedo=0.5", "--grid", "iso:step=45", "--out", "X", "--sed", "3"],
     "gonio simulate: unrecognized arguments: --sed 3; `gonio simulate --help` shows every argument"),
    (["export", "X", "--format", "bsdf", "--out", "x.bsdf", "--forse"], "gonio export: unrecognized"),
    (["simulat"], "gonio: argument COMMAND: invalid choice: 'simulat'"),
])
def test_a_mistake_in_the_command_line_is_one_line_naming_the_argument(argv, message, capsys, tmp_path):
    """argparse's own refusals (a required option missing, an unknown one, a bad choice) are one line,
    exit code 2, as every other user error: they were argparse's usage block and an error line, and an
    unknown option was refused by `gonio`, not by the command it was given to."""
    argv = [str(tmp_path / a) if a == "X" else a for a in argv]
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 2
    _one_clear_line(capsys, message)
    assert not (tmp_path / "X").exists()


@pytest.mark.parametrize("argv, message", [
    (["gantry", "move", "--config", "sim", "--theta-i", "30"],
     "gonio gantry: move: give --theta-i, --phi-i, --theta-o and --phi-o"),
    (["gantry", "jog", "--config", "sim"], "gonio gantry: jog: give --axis (one of light_azimuth"),
    (["config", "show"], "gonio config: show: give NAME, a shipped config (one of: emulated-"),
])
def test_a_subcommand_short_of_its_arguments_is_one_line_said_once(argv, message, capsys):
    """It read `gonio gantry: gonio gantry move: give ...` (and `gonio config: gonio config show: ...`)."""
    assert main(argv) == 2
    assert _one_clear_line(capsys, message).count("gonio") == 1


def test_plan_help_spells_each_grid_kind_as_the_parser_takes_it():
    """`gonio plan --help` showed `adaptive:budget=S`, which the parser refuses (poses or budget_s)."""
    from gonio.cli.parsers import grid_help
    from gonio.plan import parse_grid
    from gonio.registries import GRID_KINDS

    examples = re.findall(r"^  ([a-z]+):(\w+)=([A-Z])\b", grid_help(), re.M)
    assert sorted(k for k, _, _ in examples) == sorted(k.name for k in GRID_KINDS.entries())
    values = {"S": "30", "K": "4", "N": "60", "T": "600"}
    for kind, option, letter in examples:
        assert parse_grid(f"{kind}:{option}={values[letter]}").kind == kind


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
    from gonio.campaign import create_campaign, open_campaign
    from gonio.config import load_config
    from gonio.lifecycle import run_campaign
    from gonio.wiring import build_gantry

    out = tmp_path / "run"
    create_campaign(out, load_config(), grid="iso:step=45", material="lambert:albedo=0.5").close()

    def crash(n):
        if n == 5:  # the start event, then four committed steps
            raise Crash

    c = open_campaign(out, write_hook=crash)
    gantry = build_gantry(c.cfg, "lambert:albedo=0.5")
    gantry.detector.chunk = 1   # one step a unit: a write per step (the resumed run takes chunks)
    with pytest.raises(Crash):
        run_campaign(c, gantry)
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


# -- user mistakes: one line, exit 2, nothing written --------------------------------------------
SIM = ["simulate", "lambert:albedo=0.5", "--grid", "iso:step=45", "--quiet"]


def test_out_that_is_a_file_is_refused(tmp_path, capsys):
    f = tmp_path / "notes.txt"
    f.write_text("x")
    assert main([*SIM, "--out", str(f)]) == 2
    _one_clear_line(capsys, "--out", str(f), "is a file")
    assert f.read_text() == "x"


def test_simulate_on_a_gantry_with_a_real_detector_points_to_gonio_run(tmp_path, capsys):
    """It said "name the sample ('sample'), not a material": gonio simulate takes no sample."""
    assert main([*SIM, "--out", str(tmp_path / "run"), "--config", "two-arm-dynamixel"]) == 2
    _one_clear_line(capsys, "--config: gantry 'two-arm-dynamixel' has a real detector",
                    "`gonio run ... --sample NAME`")
    assert not (tmp_path / "run").exists()


def test_a_folder_holding_a_brdf_h5_of_no_campaign_is_refused_and_the_file_kept(tmp_path, capsys):
    """A new campaign there replaced the file silently when it ended (a brdf.h5 copied or fetched into
    the folder, its journal left elsewhere)."""
    folder = tmp_path / "run"
    folder.mkdir()
    (folder / "brdf.h5").write_bytes(b"someone's data")
    assert main([*SIM, "--out", str(folder)]) == 2
    _one_clear_line(capsys, f"--out: {folder} holds a brdf.h5 of no campaign (no campaign.sqlite beside it)")
    assert sorted(p.name for p in folder.iterdir()) == ["brdf.h5"]
    assert (folder / "brdf.h5").read_bytes() == b"someone's data"


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_read_only_folder_is_refused(tmp_path, capsys):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        assert main([*SIM, "--out", str(ro / "run")]) == 2
        _one_clear_line(capsys, "not writable")
    finally:
        ro.chmod(0o755)


@pytest.mark.skipif(os.geteuid() != 0 or not Path("/sys/kernel").is_dir(), reason="root, on Linux's sysfs")
def test_a_folder_root_cannot_create_is_one_line_naming_out(tmp_path, capsys):
    """Root passes every permission check; sysfs still refuses a new folder (EPERM)."""
    assert main([*SIM, "--out", "/sys/gonio-test-run"]) == 2
    _one_clear_line(capsys, "--out", "/sys/gonio-test-run", "cannot be written")


def test_read_only_folder_is_refused_even_for_root(tmp_path, capsys, monkeypatch):
    """Root ignores permission bits; what root cannot write is a read-only mount. os.access is what
    gonio asks, so the check is shown by making it answer no."""
    ro = tmp_path / "ro"
    ro.mkdir()
    real = os.access
    monkeypatch.setattr(os, "access", lambda p, mode: False if Path(p) == ro else real(p, mode))
    assert main([*SIM, "--out", str(ro / "run")]) == 2
    _one_clear_line(capsys, str(ro), "not writable")
    assert list(ro.iterdir()) == []


def test_config_that_is_a_folder_or_missing_is_one_line(tmp_path, capsys):
    assert main(["plan", "--grid", "iso:step=30", "--config", str(tmp_path)]) == 2
    _one_clear_line(capsys, str(tmp_path), "is a folder")
    assert main(["plan", "--grid", "iso:step=30", "--config", str(tmp_path / "none.toml")]) == 2
    _one_clear_line(capsys, "none.toml", "no such config file")
    assert main(["plan", "--grid", "iso:step=30", "--config", "no-such-gantry"]) == 2
    _one_clear_line(capsys, "no-such-gantry", "shipped:", "sim")


def test_bad_seed_is_refused_before_anything_is_written(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        main([*SIM, "--out", str(tmp_path / "run"), "--seed", "-3"])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert "--seed" in err and "integer in [0, 9223372036854775807]" in err and "Traceback" not in err
    assert not (tmp_path / "run").exists()


def test_a_seed_past_64_bits_is_refused_before_anything_is_written(tmp_path, capsys):
    """brdf.h5 stores the seed as a signed 64-bit integer; one more once ran the whole campaign, then failed
    writing brdf.h5 with h5py's traceback and a half-made folder."""
    for seed in (str(2**63), "99999999999999999999999"):
        with pytest.raises(SystemExit) as exit_:
            main([*SIM, "--out", str(tmp_path / "run"), "--seed", seed])
        assert exit_.value.code == 2
        err = capsys.readouterr().err
        assert f"argument --seed: must be an integer in [0, {2**63 - 1}], got {seed}" in err
        assert "Traceback" not in err and not (tmp_path / "run").exists()
    assert not (tmp_path / "run").exists()


def test_paths_with_brackets_print_as_they_are(tmp_path, capsys):
    out = tmp_path / "run [red]1[/red]"
    assert main([*SIM, "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert f"wrote {out / 'brdf.h5'}" in err


def test_resume_refuses_another_seed_or_config_and_names_the_field(tmp_path, capsys):
    out = tmp_path / "run"
    create_campaign_args = [*SIM, "--out", str(out), "--seed", "4"]
    from gonio.campaign import create_campaign
    from gonio.config import load_config

    create_campaign(out, load_config(), grid="iso:step=45", material="lambert:albedo=0.5", seed=4).close()
    assert main([*SIM, "--out", str(out), "--seed", "5"]) == 2
    _one_clear_line(capsys, "seed: 4 in the campaign, 5 now")
    assert main([*create_campaign_args, "--config", "sample-stage"]) == 2
    _one_clear_line(capsys, "config:", "holds another campaign")
    # The same material spelled differently is the same campaign.
    argv = ["simulate", "lambert:albedo=0.50", "--grid", "iso:step=45", "--out", str(out), "--seed", "4",
            "--quiet"]
    assert main(argv) == 0


def test_version_and_help_show_defaults(capsys):
    from gonio.campaign import software_version

    with pytest.raises(SystemExit) as exit_:
        main(["--version"])
    assert exit_.value.code == 0 and capsys.readouterr().out.strip() == f"gonio {software_version()}"
    with pytest.raises(SystemExit):
        main(["simulate", "--help"])
    out = " ".join(capsys.readouterr().out.split())  # help text wraps to the terminal's width
    assert "random numbers (default: 0)" in out and "--clear-fault" in out and "(default: None)" not in out


def test_config_list_and_show(capsys):
    assert main(["config", "list"]) == 0
    out = capsys.readouterr().out
    assert "sim " in out and "sample-stage" in out and "two-arm" in out
    assert main(["config", "show", "sample-stage"]) == 0
    assert 'design = "sample-stage"' in capsys.readouterr().out


# -- status, progress and signals (the signals to a process) ----------------------------------------

def test_progress_is_plain_lines_when_stderr_is_not_a_terminal(tmp_path, capsys):
    # This process's stderr, captured: not a terminal (the console script runs as a process of its own
    # above).
    capsys.readouterr()
    assert main(["simulate", "lambert:albedo=0.5", "--grid", "iso:step=45", "--out",
                 str(tmp_path / "run")]) == 0
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.startswith("measuring: ")]
    assert lines and "steps (100 %)" in lines[-1]
    assert lines[-1].endswith("ETA 0:00:00")   # it said "ETA ?" where the run was too short for a pace
    assert "\x1b[" not in err  # no terminal control codes in a log


def test_a_message_off_a_terminal_is_what_rich_writes_there_without_emoji_codes(capsys, monkeypatch):
    """Off a terminal a message is written without rich (gonio.cli.common.Out): as rich's console writes it
    there (tabs to stops of 8, control codes dropped, no style), except that ``:fire:`` in a path stays
    as typed (rich made it an emoji), on a terminal too."""
    import io

    from rich.console import Console

    from gonio.cli.common import Out

    for var in ("TTY_COMPATIBLE", "FORCE_COLOR"):
        monkeypatch.delenv(var, raising=False)
    text = "wrote /data/:fire:/brdf.h5\tin 2 s\r\x07, [bold]done[/]"
    capsys.readouterr()
    Out()(text, style="red")
    err = capsys.readouterr().err
    assert err == "wrote /data/:fire:/brdf.h5      in 2 s, [bold]done[/]\n"
    rich = Console(file=io.StringIO(), soft_wrap=True, highlight=False, emoji=False)
    rich.print(text, style="red", markup=False)
    assert rich.file.getvalue() == err


def test_a_fit_too_small_to_judge_its_residual_structure_says_so(tmp_path, capsys):
    """On 5 samples each residual has a (θh, θd) bin to itself: the fit printed `structure nan`."""
    out = tmp_path / "run"
    assert main([*SIM, "--out", str(out)]) == 0
    capsys.readouterr()
    assert main(["fit", str(out), "--model", "lambert"]) == 0
    err = capsys.readouterr().err
    assert "nan" not in err and "structure not judged (no two residuals share a (θh, θd) bin" in err


def test_status_reads_a_campaign_while_it_is_not_running(tmp_path, capsys):
    out = tmp_path / "run"
    assert main([*SIM, "--out", str(out)]) == 0
    capsys.readouterr()
    assert main(["status", str(out), "--json"]) == 0
    st = json.loads(capsys.readouterr().out)
    assert st["state"] == "done" and st["steps_done"] == st["steps"] > 0
    assert st["latched_fault"] is None and st["estimated_remaining_s"] == 0.0
    assert main(["status", str(tmp_path)]) == 2
    _one_clear_line(capsys, "not a campaign folder")
    assert main(["status", str(out / "brdf.h5")]) == 2   # a file: it said "no such folder"
    _one_clear_line(capsys, f"{out / 'brdf.h5'}: a file, not a campaign folder")
    assert main(["status", str(tmp_path / "nothing")]) == 2
    _one_clear_line(capsys, "nothing: no such folder")


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_mid_campaign_pauses_parks_journals_and_says_how_to_resume(tmp_path, capsys, sig):
    from gonio.store import JOURNAL_NAME, Journal

    out = tmp_path / "run"
    argv = [sys.executable, "-m", "gonio.cli", "simulate", "ggx:alpha=0.2,metal=gold", "--grid",
            "iso:step=10,order=serpentine", "--out", str(out), "--quiet"]  # long; quick to plan
    p = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    try:
        while time.monotonic() < deadline and p.poll() is None:
            if (out / JOURNAL_NAME).exists():
                j = Journal.open(out / JOURNAL_NAME, readonly=True)
                done = j.done_count()
                j.close()
                if done >= 20:
                    break
            time.sleep(0.005)
        p.send_signal(sig)
        _, err = p.communicate(timeout=120)
    finally:
        p.kill()
    assert p.returncode == 130, err
    assert "Traceback" not in err
    assert f"interrupted ({signal.Signals(sig).name})" in err and "run the same command to resume" in err
    j = Journal.open(out / JOURNAL_NAME, readonly=True)
    kinds = [e["kind"] for e in j.events()]
    assert "signal" in kinds and kinds[-1] == "park"
    assert j.last_event("park")["axes_deg"] == [0.0, 0.0, 180.0, 0.0]  # home
    assert j.last_event("state")["state"] == "paused"
    j.close()
    assert main(["status", str(out)]) == 0
    assert "paused" in capsys.readouterr().out


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_inside_a_journal_transaction_pauses_cleanly(tmp_path, capsys, monkeypatch, sig):
    """The handler runs in the main thread wherever it is, here between the BEGIN and the COMMIT of a
    step's measurement: the pause and its journal event must not nest a transaction in that one."""
    from gonio.store import JOURNAL_NAME, Journal

    real_write, real_many, rows = Journal._write, Journal._write_many, []

    def committed(sql, n):
        if sql.startswith("INSERT INTO measurements"):
            rows.append(n)
            if sum(rows) >= 10 > sum(rows) - n:     # inside the transaction that holds the 10th step
                os.kill(os.getpid(), sig)

    def write(self, sql, params=()):
        real_write(self, sql, params)
        committed(sql, 1)

    def write_many(self, sql, many):
        many = list(many)
        real_many(self, sql, many)
        committed(sql, len(many))     # a chunk of steps: one transaction

    monkeypatch.setattr(Journal, "_write", write)
    monkeypatch.setattr(Journal, "_write_many", write_many)
    out = tmp_path / "run"
    argv = ["simulate", "lambert:albedo=0.5", "--grid", "iso:step=15", "--quiet", "--out", str(out)]
    assert main(argv) == 130
    err = capsys.readouterr().err
    assert "Traceback" not in err and "run the same command to resume" in err
    j = Journal.open(out / JOURNAL_NAME, readonly=True)
    try:
        kinds = [e["kind"] for e in j.events()]
        assert "signal" in kinds and kinds[-1] == "park" and j.last_event("state")["state"] == "paused"
        assert j.done_count() >= 10 and j.done_steps().tolist() == list(range(j.done_count()))
    finally:
        j.close()
    monkeypatch.undo()
    assert main(argv) == 0


class _InlineThread:
    """threading.Thread for the CLI's signal actors, run at once in the signalled thread: the second
    signal then acts at a known point (the test sends it from inside a move command)."""

    def __init__(self, target, args=(), name=None, daemon=None):
        self.target, self.args = target, args

    def start(self):
        self.target(*self.args)

    def join(self, timeout=None):
        pass


def test_a_second_signal_while_the_pause_parks_halts_and_says_halted(tmp_path, capsys, monkeypatch):
    import gonio.cli.campaigns
    from gonio.sim.axis import SimAxis
    from gonio.store import JOURNAL_NAME, Journal

    monkeypatch.setattr(gonio.cli.campaigns.threading, "Thread", _InlineThread)
    real_write, real_move = Journal._write, SimAxis.move_to
    seen = {"moves": 0, "paused": False, "second": False}

    def write(self, sql, params=()):
        real_write(self, sql, params)
        if sql.startswith("INSERT INTO events") and "paused" in params:
            seen["paused"] = True        # the runner journals 'paused', then parks

    def move_to(self, target):
        real_move(self, target)
        seen["moves"] += 1
        if seen["moves"] == 20:
            os.kill(os.getpid(), signal.SIGINT)          # the first: pause
        elif seen["paused"] and not seen["second"]:
            seen["second"] = True
            os.kill(os.getpid(), signal.SIGINT)          # the second, while parking: halt

    monkeypatch.setattr(Journal, "_write", write)
    monkeypatch.setattr(SimAxis, "move_to", move_to)
    out = tmp_path / "run"
    argv = ["simulate", "lambert:albedo=0.5", "--grid", "iso:step=15", "--quiet", "--out", str(out)]
    assert main(argv) == 130
    err = capsys.readouterr().err
    assert seen["second"] and "interrupted (SIGINT): halted at step" in err and "paused" not in err, err
    j = Journal.open(out / JOURNAL_NAME, readonly=True)
    try:
        assert j.last_event("state")["state"] == "halted"
        assert [e for e in j.events() if e["kind"] == "fault"] == []   # was: 'park failed: ' (no reason)
    finally:
        j.close()
    monkeypatch.undo()
    assert main(argv) == 0


def test_a_campaign_another_process_runs_is_refused_naming_its_pid(tmp_path, capsys):
    from gonio.campaign import CampaignLock

    out = tmp_path / "run"
    argv = [*SIM, "--out", str(out)]
    assert main(argv) == 0
    capsys.readouterr()
    lock = CampaignLock(out).acquire()      # as `gonio simulate` in another process holds it
    try:
        assert main(argv) == 2
        _one_clear_line(capsys, str(out), f"another gonio process (pid {os.getpid()})")
    finally:
        lock.release()
    assert main(argv) == 0


def _disk_full_at(monkeypatch, creating: list[int], running: list[int]):
    """Journal writes fail as SQLite's do on a full disk: the n-th write statement of the journal's
    creation for n in ``creating``, and the n-th of the journals opened to run for n in ``running``."""
    from gonio.store import Journal

    def hook(count: list, writes: list):
        def fail(_n):
            count[0] += 1
            if count[0] in writes:
                err = sqlite3.OperationalError("database or disk is full")
                err.sqlite_errorcode = sqlite3.SQLITE_FULL
                raise err
        return fail

    create, open_ = Journal.create.__func__, Journal.open.__func__
    created, opened = hook([0], creating), hook([0], running)
    monkeypatch.setattr(Journal, "create", classmethod(lambda cls, path, meta, steps, write_hook=None:
                                                       create(cls, path, meta, steps, write_hook=created)))
    monkeypatch.setattr(Journal, "open", classmethod(lambda cls, path, write_hook=None, readonly=False:
                                                     open_(cls, path, write_hook=None if readonly else opened,
                                                           readonly=readonly)))


@pytest.mark.parametrize("creating, running, says", [
    ([1], [], "the disk is full (database or disk is full); nothing was written"),
    # full from the run's 5th write on (of 12): the fault cannot be latched either
    ([], list(range(5, 10_000)),
     "the disk is full (database or disk is full); the journal in {out} keeps every committed step: "
     "free some space, then run the same command to resume"),
    # one write fails; the journal latches the fault with the bytes left
    ([], [5], "the disk is full (database or disk is full); the journal in {out} keeps every committed step: "
              "free some space, then run the same command with --clear-fault to resume"),
])
def test_a_full_disk_is_one_line_and_the_same_command_resumes(tmp_path, capsys, monkeypatch, creating,
                                                              running, says):
    """SQLite's "database or disk is full" at the journal's creation or mid-campaign came out as three
    chained tracebacks. Once space is freed the command the line names finishes the campaign."""
    out = tmp_path / "run"
    with monkeypatch.context() as m:
        _disk_full_at(m, creating, running)
        assert main([*SIM, "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == f"gonio simulate: {says.format(out=out)}" and "Traceback" not in "".join(err)
    resume = [*SIM, "--out", str(out)] + (["--clear-fault"] if "--clear-fault" in says else [])
    assert main(resume) == 0
    assert (out / "brdf.h5").exists()


@pytest.mark.parametrize("old, new, says", [
    ("min_deg = -200.0", "min_deg = nan", "axes.light_azimuth.min_deg: Input should be a finite number"),
    ("home_deg = 180.0", "home_deg = inf", "axes.detector_azimuth.home_deg: Input should be a finite number"),
    # 1e-300 °/s passed and the planner failed on it: "--grid: cannot reshape array of size 0"
    ("max_velocity_deg_s = 60.0", "max_velocity_deg_s = 1e-300",
     "axes.light_azimuth.max_velocity_deg_s: Input should be greater than or equal to 0.001"),
    # an escape sequence and a line break went to the terminal as they were
    ('name = "sim-two-arm"', 'name = "a\\u001b[2Jb\\nc"', "name: must be 1 to 120 printable characters"),
    # three missing keys were three lines
    ("[axes.light_azimuth]", "[axes.extra]\nmin_deg = 0\n[axes.light_azimuth]",
     "axes.extra.max_deg: Field required; axes.extra.max_velocity_deg_s: Field required; "
     "axes.extra.max_accel_deg_s2: Field required"),
])
def test_a_config_value_no_gantry_has_is_one_line(tmp_path, capsys, old, new, says):
    from gonio.config import resolve_config

    text = resolve_config("sim").read_text()
    assert old in text
    path = tmp_path / "c.toml"
    path.write_text(text.replace(old, new, 1))
    assert main(["plan", "--grid", "iso:step=45", "--config", str(path)]) == 2
    _one_clear_line(capsys, f"gonio plan: {path}: {says}")


def test_a_reader_that_leaves_the_pipe_ends_the_command_quietly(monkeypatch):
    """`gonio plan --json | head -2`: the rest of the output goes nowhere; it said "gonio plan: [Errno 32]
    Broken pipe" and exit 2."""
    read, write = os.pipe()
    os.close(read)
    out = os.fdopen(write, "w")
    err = io.StringIO()
    monkeypatch.setattr(sys, "stdout", out)
    monkeypatch.setattr(sys, "stderr", err)
    try:
        assert main(["plan", "--grid", "iso:step=45", "--json"]) == 128 + signal.SIGPIPE
    finally:
        out.close()
    assert err.getvalue() == ""
