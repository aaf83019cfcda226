"""The campaign lifecycle: journals written before campaign kinds were recorded resume, request rules in
one place, open-or-create naming the field that differs, status."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from gonio.campaign import create_campaign, kind_of, open_campaign
from gonio.config import load_config
from gonio.dataset import read_brdf
from gonio.lifecycle import (
    CampaignMismatch,
    Request,
    RequestError,
    campaign_gantry,
    check_request,
    is_complete,
    open_or_create,
    plan_request,
    run_campaign,
    status,
)
from gonio.runner import State
from gonio.store import JOURNAL_NAME, Journal

OLD = Path(__file__).parent / "fixtures" / "old-journals"
#: What tests/fixtures/make_old_journals.py asked of the code before kinds (commit fda9ddd).
OLD_CAMPAIGNS = {
    "stop-and-go": ("iso:step=30", "lambert:albedo=0.5", 1),
    "fly": ("iso:step=30,order=fly", "ward:rho_d=0.1,rho_s=0.05,alpha_x=0.1,alpha_y=0.3", 3),
}
FIELDS = ("value", "stddev", "theta_i", "phi_i", "theta_o", "phi_o", "campaign_s", "step", "pose")


def _run(folder, material):
    c = open_campaign(folder)
    try:
        state, runner = run_campaign(c, campaign_gantry(c, material))
        return state, runner, c.meta
    finally:
        c.close()


def test_a_fly_journal_of_the_first_motion_model_is_refused_naming_it_nothing_written(tmp_path):
    """The fly fixture's lines ran at constant velocity with run-ups beyond their ends; today's run rest
    to rest between their end poses (gonio.plan.fly.FLY_MOTION 2), so its sweeps cannot be timed as
    planned: resuming it is refused before anything moves or is written."""
    old = tmp_path / "old"
    shutil.copytree(OLD / "fly", old)

    def done():
        j = Journal.open(old / JOURNAL_NAME, readonly=True)
        try:
            return j.done_count(), [m.step for m in j.measurements()]
        finally:
            j.close()

    before = done()
    c = open_campaign(old)
    try:
        with pytest.raises(ValueError, match="fly motion model 1 .* model 2"):
            run_campaign(c, campaign_gantry(c, OLD_CAMPAIGNS["fly"][1]))
    finally:
        c.close()
    assert done() == before and before[0] > 0 and not (old / "brdf.h5").exists()


@pytest.mark.parametrize("kind", sorted(set(OLD_CAMPAIGNS) - {"fly"}))
def test_a_journal_written_before_kinds_resumes_and_equals_an_uninterrupted_run(tmp_path, kind):
    """The fixture is a journal the code before this redesign wrote and a crash cut short (no ``kind`` in
    its meta; the fly one ran through the simulated-fly executor of the time). Today's lifecycle infers
    its kind, resumes it, and writes the brdf.h5 an uninterrupted campaign of today writes, bit for bit."""
    grid, material, seed = OLD_CAMPAIGNS[kind]
    old = tmp_path / "old"
    shutil.copytree(OLD / kind, old)
    j = Journal.open(old / JOURNAL_NAME, readonly=True)
    try:
        meta, done, total = j.meta(), j.done_count(), j.step_count()
    finally:
        j.close()
    assert "kind" not in meta and 0 < done < total     # written before kinds; cut short mid-way
    assert kind_of(meta) == kind
    state, _, _ = _run(old, material)
    assert state == State.DONE
    new = create_campaign(tmp_path / "new", load_config(), grid=grid, material=material, seed=seed)
    assert new.kind == kind
    new.close()
    assert _run(tmp_path / "new", material)[0] == State.DONE
    a, b = read_brdf(old / "brdf.h5"), read_brdf(tmp_path / "new" / "brdf.h5")
    assert len(a.value) > 10
    for name in FIELDS:
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    j = Journal.open(old / JOURNAL_NAME, readonly=True)
    try:
        events = j.events()
    finally:
        j.close()
    assert [e["kind"] for e in events].count("unclean-stop") == 1   # the crash is said, once


def test_request_rules_name_the_field():
    sim = load_config("sim")
    with pytest.raises(RequestError) as e:
        check_request(sim, Request("iso:step=30"))
    assert e.value.field == "material" and "MATERIAL" in str(e.value)
    with pytest.raises(RequestError) as e:
        check_request(sim, Request("iso:step=30", material="lambert:albedo=7"))
    assert e.value.field == "material"
    material = check_request(sim, Request("iso:step=30", material="lambert:albedo=0.50"))
    assert material.spec == "lambert:albedo=0.5"
    real = load_config("two-arm-dynamixel")
    with pytest.raises(RequestError) as e:
        check_request(real, Request("iso:step=30", material="lambert:albedo=0.5", sample="felt"))
    assert e.value.field == "material" and "real detector" in str(e.value)
    with pytest.raises(RequestError) as e:
        check_request(real, Request("iso:step=30"))
    assert e.value.field == "sample"
    assert check_request(real, Request("iso:step=30", sample="felt")) is None
    # the loader is the caller's: the daemon's refuses what names a path
    seen = []
    check_request(sim, Request("iso:step=30", material="lambert:albedo=0.5"),
                  load=lambda spec: seen.append(spec) or load_material(spec))
    assert seen == ["lambert:albedo=0.5"]


def load_material(spec):
    from gonio.sim.materials import load

    return load(spec)


def test_plan_request_gives_the_kind_and_refuses_a_gantry_that_cannot_fly():
    sim = load_config("sim")
    material = load_material("lambert:albedo=0.5")
    assert plan_request(sim, Request("iso:step=30"), material).kind == "stop-and-go"
    fly = plan_request(sim, Request("iso:step=30,order=fly"), material)
    assert fly.kind == "fly" and fly.fly is not None and fly.steps == sum(ln.n for ln in fly.fly.lines) + \
        2 * int(fly.fly.checkpoint_before.sum())
    with pytest.raises(RequestError) as e:   # Modbus axes cannot sweep
        plan_request(load_config("sample-stage-modbus"), Request("iso:step=30,order=fly", sample="x"))
    assert e.value.field == "gantry" and "driver 'modbus' cannot sweep" in str(e.value)
    with pytest.raises(RequestError) as e:
        plan_request(sim, Request("iso:step=0"), material)
    assert e.value.field == "grid"


def test_open_or_create_resumes_the_same_campaign_and_names_the_field_that_differs(tmp_path):
    cfg = load_config("sim")
    req = Request("iso:step=45", material="lambert:albedo=0.5", seed=1)
    c, created = open_or_create(tmp_path / "c", cfg, req, spec="lambert:albedo=0.5")
    assert created and c.kind == "stop-and-go" and c.meta["kind"] == "stop-and-go"
    c.close()
    c, created = open_or_create(tmp_path / "c", cfg, req, spec="lambert:albedo=0.5",
                                plan=lambda: pytest.fail("a campaign that exists is not planned again"))
    assert not created and not is_complete(c)
    c.close()
    with pytest.raises(CampaignMismatch) as e:
        open_or_create(tmp_path / "c", cfg, Request("iso:step=45", material="lambert:albedo=0.5", seed=2),
                       spec="lambert:albedo=0.5")
    assert e.value.difference == "seed: 1 in the campaign, 2 now"
    st = status(tmp_path / "c")
    assert st["state"] == "created" and st["kind"] == "stop-and-go" and st["pid"] is None
    with pytest.raises(FileNotFoundError):
        status(tmp_path / "nothing")
