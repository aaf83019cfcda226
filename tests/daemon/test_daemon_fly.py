"""Fly campaigns through the daemon: on a configured gantry (the emulated Dynamixel twin, the emulators'
synced virtual clock) a request with ``order=fly`` is journaled as a fly campaign and flown sweep by
sweep through the runner, as ``gonio run`` does; where it cannot fly, the request is refused naming the
grid, and nothing is queued."""

from __future__ import annotations

import numpy as np
from daemon_helpers import wait_state

from gonio.config import load_config, parse_config
from gonio.dataset import read_brdf
from gonio.sim.emulators.gantry import EmulatedGantry
from gonio.sim.emulators.link import SyncedVirtualClock
from gonio.store import JOURNAL_NAME, Journal

MATERIAL = "cook-torrance:d=beckmann,m=0.3,metal=gold"


def test_the_daemon_flies_a_campaign_on_the_dynamixel_twin(serve, tmp_path):
    clock = SyncedVirtualClock()
    twin = load_config("emulated-two-arm-dynamixel")
    with EmulatedGantry(twin, MATERIAL, clock=clock, any_port=True) as emu:
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
    # The simulated gantry: the daemon points at gonio simulate.
    d = serve()
    r = d.client.post("/campaigns", json={"grid": "iso:step=30,order=fly", "material": "lambert:albedo=0.5"})
    assert r.status_code == 422, r.text
    (err,) = r.json()["detail"]
    assert err["loc"] == ["body", "grid"] and "gonio simulate" in err["msg"]
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
