"""Fly campaigns through the daemon: on a configured gantry (the emulated Dynamixel twin, the emulators'
synced virtual clock) or the simulated one, a request with ``order=fly`` is journaled as a fly campaign
and flown sweep by sweep through the engine, as ``gonio run`` and ``gonio simulate`` do, with the
operator's pause, halt, resume and abort acting between (or, a halt, within) sweeps; where it cannot fly,
the request is refused naming the grid, and nothing is queued."""

from __future__ import annotations

import time

import numpy as np
from daemon_helpers import unpace, wait_for, wait_state

from gonio.campaign import open_campaign
from gonio.config import load_config, parse_config
from gonio.dataset import read_brdf
from gonio.fly import fly_plan_of
from gonio.plan.fly import fly_steps
from gonio.sim.emulators.gantry import EmulatedGantry
from gonio.sim.emulators.link import SyncedVirtualClock
from gonio.store import JOURNAL_NAME, Journal

MATERIAL = "cook-torrance:d=beckmann,m=0.3,metal=gold"


def test_the_daemon_flies_a_campaign_on_the_dynamixel_twin(serve, tmp_path):
    clock = SyncedVirtualClock()
    twin = load_config("emulated-two-arm-dynamixel")
    with EmulatedGantry(twin, MATERIAL, clock=clock, any_port=True, referenced=True) as emu:
        d = serve(cfg=emu.config(), clock=clock)
        r = d.client.post("/campaigns", json={"grid": "iso:step=30,order=fly", "sample": "gold"})
        assert r.status_code == 201, r.text
        cid = r.json()["id"]
        st = wait_state(d.client, cid, {"done", "faulted", "halted"})
        assert st["state"] == "done", st
        folder = tmp_path / "data" / "campaigns" / cid
        j = Journal.open(folder / JOURNAL_NAME, readonly=True)
        try:
            meta, rows, events = j.meta(), j.measurements(), j.events()
        finally:
            j.close()
    assert meta["fly"]["lines"] >= 4 and meta["stop_and_go_estimated_s"] > meta["estimated_s"]
    swept = [m for m in rows if m.frames > 1]
    assert len(swept) == meta["poses"]   # every pose read while its line swept
    assert not [e for e in events if e["kind"] in ("retry", "fault")]
    b = read_brdf(folder / "brdf.h5")
    assert b.value.shape[0] == meta["poses"] and np.all(np.isfinite(b.value)) and np.all(b.stddev > 0)


def test_a_fly_request_the_gantry_cannot_fly_is_refused_naming_the_grid(serve, tmp_path):
    # The simulated gantry with its camera: a frame per reading cannot be read on the fly.
    data = load_config("sim").model_dump(mode="json")
    data["detector"].setdefault("sim", {})["kind"] = "camera"
    d = serve(cfg=parse_config(data))
    r = d.client.post("/campaigns", json={"grid": "iso:step=30,order=fly", "material": "lambert:albedo=0.5"})
    assert r.status_code == 422, r.text
    (err,) = r.json()["detail"]
    assert err["loc"] == ["body", "grid"] and "'camera' cannot be simulated on the fly" in err["msg"]
    # A Modbus gantry: its sweeping axes are not Dynamixel servos (refused before anything is written).
    data = load_config("emulated-sample-stage-modbus").model_dump(mode="json")
    d2 = serve(cfg=parse_config(data), data=tmp_path / "modbus")
    r = d2.client.post("/campaigns", json={"grid": "iso:step=30,order=fly", "sample": "felt"})
    assert r.status_code == 422, r.text
    (err,) = r.json()["detail"]
    assert err["loc"] == ["body", "grid"] and "driver 'modbus' cannot sweep" in err["msg"]
    for daemon in (d, d2):
        assert daemon.client.get("/campaigns").json()["campaigns"] == []
    assert not list((tmp_path / "modbus" / "campaigns").glob("c*"))


def test_the_daemon_runs_a_simulated_fly_campaign_with_pause_halt_and_abort(serve, tmp_path):
    """The simulated gantry flies through the same engine as hardware: its sweeps are rendered, one
    unit each, while the paced clock runs, so a pause, a halt and a resume act between (a halt: within)
    sweeps; a second campaign is aborted mid-way. The finished one equals `gonio simulate` bit for bit."""
    from gonio.cli import main

    grid, material = "iso:step=15,order=fly", "lambert:albedo=0.5"
    d = serve(pace=0.002)
    cid = d.client.post("/campaigns", json={"grid": grid, "material": material}).json()["id"]
    folder = tmp_path / "data" / "campaigns" / cid
    wait_for(lambda: d.client.get(f"/campaigns/{cid}").json()["steps_done"] >= 1, "a committed sweep")
    assert d.client.post(f"/campaigns/{cid}/pause").status_code == 200
    paused = wait_state(d.client, cid, "paused")
    assert 0 < paused["steps_done"] < paused["steps"]
    assert d.client.post(f"/campaigns/{cid}/resume").status_code == 200
    wait_for(lambda: d.client.get(f"/campaigns/{cid}").json()["steps_done"] > paused["steps_done"],
             "a sweep after the resume")
    assert d.client.post("/gantry/halt").status_code == 200
    halted = wait_state(d.client, cid, "halted")
    assert halted["steps_done"] < halted["steps"]
    units, done = _units(folder)
    for first, n in units:   # whole sweeps only, the halted one dropped
        assert len({s for s in range(first, first + n) if s in done}) in (0, n)
    assert d.client.post(f"/campaigns/{cid}/resume").status_code == 200
    unpace(d.daemon, only=cid)   # its rest at once; the second keeps the pace, to be aborted mid-way
    assert wait_state(d.client, cid, {"done", "faulted"})["state"] == "done"
    second = d.client.post("/campaigns", json={"grid": grid, "material": material}).json()["id"]
    wait_for(lambda: d.client.get(f"/campaigns/{second}").json()["steps_done"] >= 1, "a committed sweep")
    assert d.client.post(f"/campaigns/{second}/abort").status_code == 200
    aborted = wait_state(d.client, second, "aborted")
    assert 0 < aborted["steps_done"] < aborted["steps"]
    j = Journal.open(folder / JOURNAL_NAME, readonly=True)
    try:
        meta, events = j.meta(), j.events()
    finally:
        j.close()
    assert meta["kind"] == "fly"
    kinds = [e["kind"] for e in events]
    assert "pause" in kinds and "halt" in kinds and "park" in kinds
    assert main(["simulate", material, "--grid", grid, "--out", str(tmp_path / "cli"), "--quiet"]) == 0
    a, b = read_brdf(folder / "brdf.h5"), read_brdf(tmp_path / "cli" / "brdf.h5")
    for name in ("value", "stddev", "theta_i", "phi_i", "theta_o", "phi_o", "campaign_s", "step", "pose"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name


class _PacedSyncedClock(SyncedVirtualClock):
    """The emulators' synced virtual clock, paced (as the daemon paces its simulated gantry): each
    virtual second takes ``pace`` real seconds, so that an operator's request lands mid-campaign."""

    def __init__(self, pace: float):
        super().__init__()
        self.pace = pace

    def sleep(self, seconds: float) -> None:
        super().sleep(seconds)
        time.sleep(max(seconds, 0.0) * self.pace)


def _units(folder):
    """Each sweep's and checkpoint's steps (first, count) of the fly campaign in ``folder``, and the
    steps the journal holds."""
    c = open_campaign(folder, readonly=True)
    try:
        fp, done, total = fly_plan_of(c), set(c.journal.done_steps().tolist()), c.journal.step_count()
    finally:
        c.close()
    units = [(first, 2 if kind == "checkpoint" else fp.lines[k].n) for kind, k, first in fly_steps(fp)]
    assert sum(n for _, n in units) == total
    return units, done


def test_pause_halt_and_resume_of_a_fly_campaign_through_the_daemon_keep_whole_sweeps(serve, tmp_path):
    """Pause after the first sweep, resume, halt mid-campaign, resume: the journal only ever holds whole
    sweeps and checkpoints (a halted sweep is dropped, then read again), and the campaign ends with one
    reading per step, every pose read on the fly."""
    clock = _PacedSyncedClock(pace=0.05)
    twin = load_config("emulated-two-arm-dynamixel")
    with EmulatedGantry(twin, MATERIAL, clock=clock, any_port=True, referenced=True) as emu:
        d = serve(cfg=emu.config(), clock=clock)
        r = d.client.post("/campaigns", json={"grid": "iso:step=30,order=fly", "sample": "gold"})
        cid = r.json()["id"]
        folder = tmp_path / "data" / "campaigns" / cid

        def whole():
            units, done = _units(folder)
            for first, n in units:
                got = {s for s in range(first, first + n) if s in done}
                assert len(got) in (0, n), (first, n, sorted(got))
            return done

        wait_for(lambda: d.client.get(f"/campaigns/{cid}").json()["steps_done"] >= 1, "a committed sweep")
        assert d.client.post(f"/campaigns/{cid}/pause").status_code == 200
        paused = wait_state(d.client, cid, "paused")
        assert 0 < paused["steps_done"] < paused["steps"]
        assert len(whole()) == paused["steps_done"]
        assert d.client.post(f"/campaigns/{cid}/resume").status_code == 200
        wait_for(lambda: d.client.get(f"/campaigns/{cid}").json()["steps_done"] > paused["steps_done"],
                 "a sweep after the resume")
        assert d.client.post("/gantry/halt").status_code == 200
        halted = wait_state(d.client, cid, "halted")   # 20 steps were left: the halt lands before the end
        assert paused["steps_done"] < halted["steps_done"] < halted["steps"]
        whole()
        clock.pace = 0.0   # the rest at once: nothing more lands mid-campaign (pacing spends wall time only)
        assert d.client.post(f"/campaigns/{cid}/resume").status_code == 200
        wait_state(d.client, cid, "done")
        assert sorted(whole()) == list(range(paused["steps"]))
        j = Journal.open(folder / JOURNAL_NAME, readonly=True)
        try:
            meta, rows, events = j.meta(), j.measurements(), j.events()
        finally:
            j.close()
    assert len(rows) == paused["steps"]   # one reading per step, none twice
    assert sum(m.frames > 1 for m in rows) == meta["poses"]
    kinds = [e["kind"] for e in events]
    assert "pause" in kinds and "park" in kinds
    assert "halt" in kinds
