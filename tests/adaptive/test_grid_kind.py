"""The ``adaptive`` grid kind: its GRID string, ``gonio plan`` (the pilot and the budget), bad input (one
line, exit 2, nothing written), and ``gonio simulate`` running the pilot and the rounds to the budget,
each round planned from the journal alone and appended to it whole."""

from __future__ import annotations

import numpy as np
import pytest
from cli_helpers import one_clear_line

from gonio.adaptive.plan import next_round, round_size
from gonio.campaign import open_campaign
from gonio.cli import main
from gonio.dataset import read_brdf
from gonio.plan.grids import parse_grid
from gonio.plan.schedule import STEP_DARK, STEP_POSE, STEP_REFERENCE

MATERIAL = "ggx:alpha=0.15,metal=gold"


def _simulate(out, grid, *extra):
    return main(["simulate", MATERIAL, "--grid", grid, "--out", str(out), "--quiet", *extra])


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    out = tmp_path_factory.mktemp("adaptive") / "c"
    assert _simulate(out, "adaptive:poses=45") == 0
    return out


def test_the_grid_string_spells_its_budget():
    spelled = parse_grid("adaptive: poses=400, theta_max=70").normalized
    assert spelled == "adaptive:poses=400,theta_max=70,order=auto"
    assert parse_grid("adaptive:budget_s=3600").budget_s == 3600.0


@pytest.mark.parametrize(("grid", "needles"), [
    ("adaptive:poses=0", ("'poses'", "from 1 to 100,000", "got 0")),
    ("adaptive:poses=2", ("'poses'", "at least the pilot's 3 poses", "got 2")),
    ("adaptive:budget_s=5", ("'budget_s'", "at least the pilot's 15 s", "got 5")),
    ("adaptive:poses=50,budget_s=60", ("exactly one of 'poses'", "'budget_s'")),
    ("adaptive:poses=50,step=5", ("unknown option 'step'", "allowed: poses, budget_s")),
    ("adaptive:poses=50,order=fly", ("order=fly", "no round of an adaptive grid can fly")),
    ("adaptive:poses=10,anisotropic=true", ("'poses'", "at least the pilot's 21 poses", "got 10")),
    ("adaptive:budget_s=5,anisotropic=true", ("'budget_s'", "at least the pilot's 45 s", "got 5")),
    ("adaptive:poses=100,anisotropic=maybe", ("'anisotropic'", "true or false", "'maybe'")),
    ("adaptive:poses=100,anisotropic=true,isotropy=true", ("'isotropy'", "false with anisotropic=true")),
])
@pytest.mark.parametrize("command", ["plan", "simulate"])
def test_bad_input_is_one_line_exit_2_and_nothing_written(tmp_path, capsys, grid, needles, command):
    out = tmp_path / "out"
    argv = ["plan", "--grid", grid] if command == "plan" else ["simulate", MATERIAL, "--grid", grid, "--out",
                                                                  str(out), "--quiet"]
    assert main(argv) == 2
    one_clear_line(capsys, *needles)
    assert not out.exists()


def test_plan_states_the_pilot_and_the_budget(capsys):
    assert main(["plan", "--grid", "adaptive:poses=1000"]) == 0
    text = capsys.readouterr().out
    assert "pilot: 66 poses (a 4-node lattice), estimated 0:01:32 (91.5 s) of gantry time" in text
    assert "budget: 1,000 poses, pilot included" in text
    assert main(["plan", "--grid", "adaptive:budget_s=900"]) == 0
    text = capsys.readouterr().out
    # the densest lattice whose plan is estimated within 10 % of the budget
    assert "budget: 900 s of gantry time" in text
    assert "pilot: 18 poses (a 3-node lattice), estimated 0:00:37" in text
    # Anisotropic: the pilot is a full grid (4D), the densest within 10 % of the budget.
    assert main(["plan", "--grid", "adaptive:budget_s=900,anisotropic=true"]) == 0
    text = capsys.readouterr().out
    assert "pilot: 36 poses (the full:step=45 grid), estimated 0:01:05 (65.0 s) of gantry time" in text
    assert main(["plan", "--grid", "adaptive:poses=300,anisotropic=true"]) == 0
    assert "pilot: 21 poses (the full:step=60 grid)" in capsys.readouterr().out


def test_an_anisotropic_campaign_measures_the_4d_domain_and_reads_back_through_gonio_brdf(tmp_path):
    """adaptive:poses=60,anisotropic=true on anisotropic Ward: 60 poses over (θi, φi, θo, φo), declared
    anisotropic, read by gonio.brdf's local fit in 4D and close to the material where it was measured."""
    from gonio.adaptive import random_pairs, weighted_l1
    from gonio.brdf import open_brdf, read_symmetries
    from gonio.sim.materials import load

    ward = "ward:rho_d=0.1,rho_s=0.05,alpha_x=0.1,alpha_y=0.3"
    out = tmp_path / "c"
    assert main(["simulate", ward, "--grid", "adaptive:poses=60,anisotropic=true", "--out", str(out),
                 "--quiet"]) == 0
    b = read_brdf(out / "brdf.h5")
    assert len(b.value) == 60
    assert b.attrs["grid"] == "adaptive:poses=60,theta_max=80,anisotropic=true,order=tour"
    assert read_symmetries(b.attrs) == {"reciprocity": True, "isotropy": False, "mirror": False}
    # Poses at many φi, past the pilot's 60° lattice.
    phi_i = np.mod(b.planned[b.planned[:, 0] > 0, 1], 360.0)
    assert np.unique(np.round(phi_i, 6)).size > 10 and np.any(np.mod(phi_i, 60.0) > 1e-6)
    brdf = open_brdf(out / "brdf.h5")
    assert (brdf.method, brdf.domain) == ("local", "full")
    # At the measured poses it returns the measurement (exact hits); anywhere else the 4D fit (measured:
    # 0.343 cosine-weighted relative L1 at 20,000 random pairs, 99 % answered, with 60 poses).
    ev = brdf.eval_deg(*b.planned.T)
    np.testing.assert_array_equal(ev.value, b.value)
    wi, wo = random_pairs(4000, np.radians(80.0), seed=1)
    error, answered = weighted_l1(brdf.eval(wi, wo).value, load(ward).eval(wi, wo), wi, wo)
    assert error < 0.45 and answered > 0.95, (error, answered)


def test_a_simulated_campaign_spends_its_pose_budget_in_journaled_rounds(campaign):
    b = read_brdf(campaign / "brdf.h5")
    assert len(b.value) == 45 and np.all(np.isfinite(b.value))
    assert b.attrs["grid"] == "adaptive:poses=45,theta_max=80,order=tour"
    c = open_campaign(campaign, readonly=True)
    try:
        meta, steps, events = c.meta, c.journal.steps(), c.journal.events()
    finally:
        c.close()
    a = meta["adaptive"]
    # pilot 3 poses, then rounds of at least 10 (the last one excepted) growing by 20 %: 10, 10, 10, 12
    assert (a["pilot_poses"], [r["poses"] for r in a["rounds"]]) == (3, [10, 10, 10, 12])
    assert meta["poses"] == 45 and round_size(a) == 0
    kind = steps["kind"]
    assert np.count_nonzero(kind == STEP_POSE) == 45
    # The pilot opens and closes with a checkpoint; the rounds follow with checkpoints as needed (the
    # shipped reference.every_s is 300 s, this campaign 80 s of gantry time): only the last round closes
    # with one. Each round's poses are numbered on from the phase before.
    first = a["rounds"][0]["first_step"]
    checkpoint = [STEP_DARK, STEP_REFERENCE]
    assert kind[:2].tolist() == kind[first - 2:first].tolist() == kind[-2:].tolist() == checkpoint
    assert np.count_nonzero(kind != STEP_POSE) == 6 and a["since_reference_s"] == 0.0
    for r in a["rounds"]:
        assert kind[r["first_step"]] == STEP_POSE
    assert sum(r["steps"] for r in a["rounds"]) == 42 + 2   # 42 poses and the closing checkpoint
    assert sorted(steps["pose"][kind == STEP_POSE].tolist()) == list(range(45))
    appended = [e for e in events if e["kind"] == "append"]
    assert [e["step"] for e in appended] == [r["first_step"] for r in a["rounds"]]
    assert appended[0]["message"].startswith("round 1: 10 poses placed from 3 samples")


def _first_round_again(folder, adaptive: dict) -> tuple[dict, dict, dict]:
    """(the first round's steps as journaled, as planned again from the pilot's readings alone with the
    ``adaptive`` meta given, the meta that planning returns): the campaign in ``folder`` is cut back to
    its pilot."""
    import sqlite3

    c = open_campaign(folder)
    try:
        first = c.meta["adaptive"]["rounds"][0]["first_step"]
        count = c.meta["adaptive"]["rounds"][0]["steps"]
        measured = {k: v[first:first + count] for k, v in c.journal.steps().items()}
        conn = sqlite3.connect(folder / "campaign.sqlite")
        with conn:
            conn.execute("DELETE FROM measurements WHERE step >= ?", (first,))
            conn.execute("DELETE FROM steps WHERE step >= ?", (first,))
        conn.close()
        c.journal.set_meta("adaptive", {**adaptive, "rounds": []})
        c.journal.set_meta("poses", adaptive["pilot_poses"])
        steps, meta, _ = next_round(c.journal, c.cfg)
    finally:
        c.close()
    return measured, steps, meta


def _same_steps(a: dict, b: dict) -> None:
    for key, value in a.items():
        assert np.asarray(b[key]).tobytes() == np.asarray(value).tobytes(), key


def test_a_journal_from_before_motion_and_checkpoints_as_needed_keeps_its_rounds(tmp_path, monkeypatch):
    """A campaign journaled without ``motion_weight`` and ``since_reference_s`` (the first adaptive
    release) plans its rounds as then: poses by error alone, every round closed by a checkpoint."""
    import gonio.adaptive.plan as adaptive_plan

    monkeypatch.setattr(adaptive_plan, "CHECKPOINTS_AS_NEEDED", False)
    monkeypatch.setattr(adaptive_plan, "MOTION_WEIGHT", 0.0)
    out = tmp_path / "old"
    assert _simulate(out, "adaptive:poses=45") == 0
    c = open_campaign(out, readonly=True)
    try:
        a = c.meta["adaptive"]
        kind = c.journal.steps()["kind"]
    finally:
        c.close()
    assert "since_reference_s" not in a and a["motion_weight"] == 0.0
    for r in a["rounds"]:
        first, count = r["first_step"], r["steps"]
        assert kind[first - 2: first].tolist() == [STEP_DARK, STEP_REFERENCE] and kind[first] == STEP_POSE
        assert kind[first + count - 2:first + count].tolist() == [STEP_DARK, STEP_REFERENCE]
    # without the key at all (as journaled then), the first round is planned again the same, whatever a
    # new campaign would journal now
    monkeypatch.setattr(adaptive_plan, "MOTION_WEIGHT", 2.0)
    measured, steps, _ = _first_round_again(out, {k: v for k, v in a.items() if k != "motion_weight"})
    _same_steps(measured, steps)


def test_a_journal_from_before_the_motion_pool_keeps_its_rounds(tmp_path, monkeypatch):
    """A campaign journaled without ``motion_pool`` (placed with a pool of 3 candidates per pose) plans
    its rounds again as then, whatever pool a new campaign journals now; the pool does change them."""
    import shutil

    import gonio.adaptive.plan as adaptive_plan

    monkeypatch.setattr(adaptive_plan, "POOL", adaptive_plan.LEGACY_POOL)
    out = tmp_path / "old"
    assert _simulate(out, "adaptive:poses=45") == 0
    c = open_campaign(out, readonly=True)
    a = c.meta["adaptive"]
    c.close()
    assert a["motion_pool"] == 3 and a["motion_weight"] > 0
    old = {k: v for k, v in a.items() if k != "motion_pool"}
    monkeypatch.undo()
    assert adaptive_plan.POOL != adaptive_plan.LEGACY_POOL
    shutil.copytree(out, tmp_path / "copy")
    measured, steps, meta = _first_round_again(out, old)
    _same_steps(measured, steps)
    assert "motion_pool" not in meta["adaptive"]
    _, other, _ = _first_round_again(tmp_path / "copy", {**old, "motion_pool": adaptive_plan.POOL})
    assert np.asarray(other["theta_o_deg"]).tobytes() != np.asarray(measured["theta_o_deg"]).tobytes()


def test_a_round_is_a_pure_function_of_the_journal(campaign, tmp_path):
    """The round after the pilot, planned again from a copy of the journal holding only the pilot's
    readings, is the one the campaign measured, bit for bit."""
    import shutil

    shutil.copytree(campaign, tmp_path / "c")
    c = open_campaign(tmp_path / "c", readonly=True)
    a = c.meta["adaptive"]
    c.close()
    measured, steps, meta = _first_round_again(tmp_path / "c", {**a, "since_reference_s": 0.0})
    _same_steps(measured, steps)
    assert meta["adaptive"]["rounds"][0]["poses"] == 10


def test_checkpoints_as_needed_bracket_every_reading_within_every_s(tmp_path):
    """With references due every 20 s of gantry time, rounds open with a checkpoint where the readings
    since the last reference and their first run would span more; every pose reading, as the journal
    timed it, lies between two reference readings at most about 20 s apart (the plans' estimates decide;
    10 % slack), the last one included."""
    from gonio.config import resolve_config

    text = resolve_config(None).read_text().replace("every_s = 300.0", "every_s = 20.0", 1)
    (tmp_path / "g.toml").write_text(text)
    out = tmp_path / "e"
    assert _simulate(out, "adaptive:poses=45", "--config", str(tmp_path / "g.toml")) == 0
    c = open_campaign(out, readonly=True)
    try:
        kind = c.journal.steps()["kind"]
        taken = {m.step: m.campaign_s for m in c.journal.measurements()}
        rounds = c.meta["adaptive"]["rounds"]
    finally:
        c.close()
    ref = np.array([taken[s] for s in np.flatnonzero(kind == STEP_REFERENCE)])
    pose = np.array([taken[s] for s in np.flatnonzero(kind == STEP_POSE)])
    after = np.searchsorted(ref, pose)
    assert np.all(after > 0) and np.all(after < ref.size)   # a reference before and after each
    assert np.max(ref[after] - ref[after - 1]) <= 20.0 * 1.1
    # some rounds open with a checkpoint, some go on from the last one
    opened = [kind[r["first_step"]] == STEP_DARK for r in rounds]
    assert any(opened) and not all(opened)


def test_a_time_budget_stops_the_rounds_within_it(tmp_path):
    out = tmp_path / "t"
    assert _simulate(out, "adaptive:budget_s=60") == 0
    c = open_campaign(out, readonly=True)
    a = c.meta["adaptive"]
    c.close()
    spent = a["pilot_s"] + sum(r["estimated_s"] for r in a["rounds"])
    assert a["rounds"] and round_size(a) == 0
    # Each round is sized to the time left at the pace so far; the last one may overrun by its own
    # estimate's error only.
    assert spent <= 60.0 * 1.2, spent


def test_the_report_shows_where_the_poses_went(campaign):
    from gonio.report import build_report

    rep = build_report(campaign, "lambert", starts=1)
    assert rep.figures["adaptive"].startswith(b"\x89PNG")
    # The shares of poses near the specular direction, from the file's planned directions: the half
    # vector's angle to the normal.
    b = read_brdf(campaign / "brdf.h5")
    p = np.radians(b.planned)
    wi = np.stack([np.sin(p[:, 0]) * np.cos(p[:, 1]), np.sin(p[:, 0]) * np.sin(p[:, 1]), np.cos(p[:, 0])], 1)
    wo = np.stack([np.sin(p[:, 2]) * np.cos(p[:, 3]), np.sin(p[:, 2]) * np.sin(p[:, 3]), np.cos(p[:, 2])], 1)
    h = wi + wo
    near = h[:, 2] / np.linalg.norm(h, axis=1) >= np.cos(np.radians(10.0))
    pilot = b.step < 7   # the pilot's 3 poses and its 4 checkpoint readings
    assert rep.adaptive == {"pilot": near[pilot].mean(), "rounds": near[~pilot].mean()}
    from html import escape

    assert escape(f"{100 * near[pilot].mean():.0f} % of the pilot's, {100 * near[~pilot].mean():.0f} % of "
                  "the rounds'") in rep.html
    assert "Adaptive acquisition: where the poses went" in rep.html
    assert "4: 10, 10, 10, 12 poses" in rep.html and "3 poses (a 2-node lattice" in rep.html
    assert "pilot feasible 3 → with the rounds 45" in rep.html
