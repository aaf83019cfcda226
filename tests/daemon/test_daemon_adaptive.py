"""An adaptive campaign through the daemon: the request is planned up to its pilot and journaled as an
``adaptive`` campaign; the engine appends its rounds as it measures, an operator's pause acts between
steps (a round appended or not), and the finished campaign holds the pose budget."""

from __future__ import annotations

import numpy as np
from daemon_helpers import unpace, wait_for, wait_state

from gonio.dataset import read_brdf
from gonio.store import JOURNAL_NAME, Journal

GRID, MATERIAL = "adaptive:poses=45", "ggx:alpha=0.15,metal=gold"


def _meta(folder):
    j = Journal.open(folder / JOURNAL_NAME, readonly=True)
    try:
        return j.meta()
    finally:
        j.close()


def test_the_daemon_runs_an_adaptive_campaign_with_a_pause_to_its_budget(serve, tmp_path):
    from gonio.cli import main

    d = serve(pace=0.002)
    r = d.client.post("/campaigns", json={"grid": GRID, "material": MATERIAL})
    assert r.status_code == 201, r.text
    cid = r.json()["id"]
    folder = tmp_path / "data" / "campaigns" / cid
    # Paused once the first round is journaled (its steps appended while the campaign ran).
    wait_for(lambda: (folder / JOURNAL_NAME).exists() and _meta(folder)["adaptive"]["rounds"], "a round")
    assert d.client.post(f"/campaigns/{cid}/pause").status_code == 200
    paused = wait_state(d.client, cid, "paused")
    assert 0 < paused["steps_done"] < 57
    assert d.client.post(f"/campaigns/{cid}/resume").status_code == 200
    unpace(d.daemon, only=cid)   # the rest at once
    done = wait_state(d.client, cid, {"done", "faulted"})
    assert done["state"] == "done", done
    meta = _meta(folder)
    assert meta["kind"] == "adaptive" and meta["poses"] == 45
    assert [r["poses"] for r in meta["adaptive"]["rounds"]] == [10, 10, 10, 12]
    b = read_brdf(folder / "brdf.h5")
    assert b.value.shape[0] == 45 and np.all(np.isfinite(b.value))
    # The same request through gonio simulate: the same rounds at the same poses. The values differ by
    # the lamp's drift over the pause's park and return (the campaign clock ran on), below 1e-6.
    assert main(["simulate", MATERIAL, "--grid", GRID, "--out", str(tmp_path / "cli"), "--quiet"]) == 0
    a = read_brdf(tmp_path / "cli" / "brdf.h5")
    for name in ("theta_i", "phi_i", "theta_o", "phi_o", "step", "pose"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    np.testing.assert_allclose(b.value, a.value, rtol=1e-6)


def test_an_adaptive_campaign_that_reaches_no_more_poses_ends_done_and_says_why(serve, tmp_path, capsys):
    """A gantry whose light cannot tilt: after the pilot no round finds a reachable pose. The daemon's
    campaign ends ``done`` (never faulted), its status and `gonio status ID` say why it ended short."""
    from zenith_gantry import zenith_light_config

    from gonio.cli import main
    from gonio.config import load_config

    d = serve(pace=0.002, cfg=load_config(zenith_light_config(tmp_path)))
    r = d.client.post("/campaigns", json={"grid": "adaptive:poses=100", "material": MATERIAL})
    assert r.status_code == 201, r.text
    cid = r.json()["id"]
    done = wait_state(d.client, cid, {"done", "faulted"})
    assert done["state"] == "done" and done["latched_fault"] is None, done
    assert done["ended_short"].startswith("round 1 found no reachable new pose")
    assert done["steps_done"] == 14
    assert main(["status", cid, "--url", d.url]) == 0
    assert f"ended short of its budget: {done['ended_short']}" in capsys.readouterr().out


def _journal_counts(folder):
    j = Journal.open(folder / JOURNAL_NAME, readonly=True)
    try:
        return j.step_count(), j.meta()["poses"]
    finally:
        j.close()


def _status_counts(client, cid):
    st = client.get(f"/campaigns/{cid}").json()
    return st["steps"], st["poses"]


def test_the_status_of_an_adaptive_campaign_counts_the_steps_its_rounds_append(serve, tmp_path):
    """The status's ``steps`` and ``poses`` follow the journal as rounds are appended (they were read
    once, at the first status request, and stayed the pilot's)."""
    d = serve(pace=0.002)
    r = d.client.post("/campaigns", json={"grid": GRID, "material": MATERIAL})
    assert r.status_code == 201, r.text
    cid = r.json()["id"]
    folder = tmp_path / "data" / "campaigns" / cid
    seen = []
    for rounds in (1, 2):
        wait_for(lambda n=rounds: (folder / JOURNAL_NAME).exists()
                 and len(_meta(folder)["adaptive"]["rounds"]) >= n, f"round {rounds}")
        assert d.client.post(f"/campaigns/{cid}/pause").status_code == 200
        wait_state(d.client, cid, "paused")
        steps, poses = _journal_counts(folder)
        # The running campaign's status is re-read from its journal at most every STATUS_TTL_S.
        wait_for(lambda counts=(steps, poses): _status_counts(d.client, cid) == counts,
                 f"the status to count {steps} steps and {poses} poses")
        seen.append(steps)
        assert d.client.post(f"/campaigns/{cid}/resume").status_code == 200
    assert seen[0] < seen[1]
    done = wait_state(d.client, cid, {"done", "faulted"})
    assert done["state"] == "done", done
    assert (done["steps"], done["poses"]) == _journal_counts(folder) and done["poses"] == 45
    assert done["progress"] == 1.0
