"""Submitting: a grid too large is refused from its parameters before any planning, planning runs in a
worker process with a time limit and stops when its client leaves, a campaign appears whole under an id
that no folder ever had, and measured materials are names in --materials, never paths."""

from __future__ import annotations

import json
import os

import httpx
import pytest
from brdf_samples import tiny_tensor_file
from daemon_helpers import WAIT_S, http_client, submit, wait_for, wait_state

from gonio.store import JOURNAL_NAME

BIG = ["full:step=0.01", "merl:stride=1", "iso:step=0.1", "full:step=2,theta_max=90"]


def _campaign_folders(r) -> list[str]:
    root = r.daemon.queue.root
    return sorted(p.name for p in root.iterdir() if not p.name.startswith("."))


def _incoming(r) -> list:
    return list((r.daemon.queue.root / ".incoming").glob("*"))


@pytest.mark.parametrize("grid", BIG)
def test_a_grid_too_large_is_refused_from_its_parameters_alone(serve, grid):
    r = serve()
    resp = r.client.post("/campaigns", json={"material": "lambert:albedo=0.5", "grid": grid})
    assert resp.status_code == 422, resp.text
    detail = resp.json()["detail"][0]
    assert detail["loc"] == ["body", "grid"]
    assert "poses exceed the 500,000 the daemon accepts" in detail["msg"]
    assert r.daemon.planner.planned == 0                  # the planner never saw it
    assert _campaign_folders(r) == [] and _incoming(r) == []


def test_planning_past_the_time_limit_is_stopped_and_leaves_nothing(serve):
    r = serve(plan_timeout_s=0.2)   # of CPU time: iso:step=2 plans for seconds
    resp = r.client.post("/campaigns", json={"material": "lambert:albedo=0.5", "grid": "iso:step=2"})
    assert resp.status_code == 422, resp.text
    assert "planning took longer than 0.2 s, the daemon's limit" in resp.json()["detail"][0]["msg"]
    assert r.daemon.planner.killed == 1 and _campaign_folders(r) == [] and _incoming(r) == []
    r.daemon.planner.timeout_s = WAIT_S
    assert submit(r.client)["id"] == "c00001"              # a fresh worker plans the next one


def test_a_client_that_goes_away_cancels_its_planning(serve):
    r = serve()
    with http_client(r.url, timeout=httpx.Timeout(WAIT_S, read=0.5)) as impatient:
        with pytest.raises(httpx.ReadTimeout):
            impatient.post("/campaigns", json={"material": "lambert:albedo=0.5", "grid": "iso:step=2"})
    wait_for(lambda: r.daemon.planner.killed == 1 and not r.daemon.planner.busy, "the planning to be stopped")
    wait_for(lambda: _incoming(r) == [], "the staging folder to be removed")
    assert _campaign_folders(r) == []
    assert submit(r.client)["id"] == "c00001"


def test_orphan_folders_are_set_aside_and_their_ids_never_reused(serve, tmp_path):
    data = tmp_path / "data"
    r = serve(data=data)
    submit(r.client)
    wait_state(r.client, "c00001", "done")
    r.stop()
    root = data / "campaigns"
    (root / "c00002").mkdir()                                        # empty, as a crash could leave it
    (root / "c00003").mkdir()
    (root / "c00003" / "daemon.json").write_text(json.dumps({"id": "c00003", "seq": 3, "request": {},
                                                             "submitted_unix": 0}))   # no journal
    (root / "c00004").mkdir()
    (root / "c00004" / JOURNAL_NAME).write_bytes(b"")                 # no daemon.json
    (root / ".incoming" / "0ddba11").mkdir(parents=True)             # a planning cut short
    r = serve(data=data)
    names = sorted(p.name for p in root.iterdir())
    assert names.pop(0) == ".incoming" and not any((root / ".incoming").iterdir())
    assert names[0] == "c00001" and [n.split("-")[0] for n in names[1:]] == ["c00002.orphan", "c00003.orphan",
                                                                             "c00004.orphan"]
    assert [c["id"] for c in r.client.get("/campaigns").json()["campaigns"]] == ["c00001"]
    assert submit(r.client)["id"] == "c00005"
    (root / "c00006").mkdir()                         # one appears while the daemon runs
    assert submit(r.client)["id"] == "c00007"
    assert not any((root / "c00006").iterdir())       # untouched


def test_measured_materials_are_names_in_the_materials_folder(serve, tmp_path):
    folder = tmp_path / "materials"
    folder.mkdir()
    tiny_tensor_file(folder / "paint.bsdf")
    os.mkfifo(folder / "pipe")
    (folder / "zero").symlink_to("/dev/zero")
    (folder / "passwd").symlink_to("/etc/passwd")
    r = serve(materials=folder)
    refused = {}
    for material in ("bsdf:pipe", "bsdf:zero", "bsdf:passwd", "bsdf:missing", "merl:pipe", "merl:zero",
                     "bsdf:/dev/zero", "merl:/etc/passwd", "bsdf:../materials/paint.bsdf", "merl:./pipe"):
        resp = r.client.post("/campaigns", json={"material": material, "grid": "iso:step=30"})
        assert resp.status_code == 422, (material, resp.text)
        detail = resp.json()["detail"][0]
        assert detail["loc"] == ["body", "material"]
        refused[material] = detail["msg"].replace(material.split(":", 1)[1], "NAME")
    # The same words whether the name is a FIFO, a link to a device or a file, or nothing at all.
    assert len({refused[m] for m in ("bsdf:pipe", "bsdf:zero", "bsdf:passwd", "bsdf:missing")}) == 1
    assert len({refused[m] for m in ("merl:pipe", "merl:zero")}) == 1
    assert all("never a path" in refused[m] for m in ("bsdf:/dev/zero", "merl:/etc/passwd",
                                                      "bsdf:../materials/paint.bsdf", "merl:./pipe"))
    assert _campaign_folders(r) == []
    st = submit(r.client, material="bsdf:paint.bsdf")
    assert st["material"] == "bsdf:paint.bsdf"
    done = wait_state(r.client, st["id"], ("done", "failed"))
    assert done["state"] == "done" and done["steps_done"] == done["steps"], done


def test_without_a_materials_folder_measured_materials_are_refused(serve):
    r = serve()
    resp = r.client.post("/campaigns", json={"material": "bsdf:paint.bsdf", "grid": "iso:step=30"})
    assert resp.status_code == 422 and "serves none (start it with --materials DIR)" in resp.text
    assert r.daemon.planner.planned == 0


def test_the_planner_plans_at_idle_priority_unless_told_otherwise(serve, tmp_path):
    """`gonio serve` plans at idle priority (the runner and the event loop first); ``plan_idle=False``
    (these tests' daemons) plans at the daemon's own. Seen from the kernel: the scheduling policy of this
    process's descendants (the planner's worker among them)."""
    import psutil

    def idle_descendants() -> list[int]:
        out = []
        for p in psutil.Process().children(recursive=True):
            try:
                if os.sched_getscheduler(p.pid) == os.SCHED_IDLE:
                    out.append(p.pid)
            except OSError:   # gone meanwhile
                pass
        return out

    r = serve(data=tmp_path / "own")          # plan_idle=False: the fixture's default
    assert submit(r.client)["id"] == "c00001"   # planned: its worker runs
    assert idle_descendants() == []
    r = serve(data=tmp_path / "idle", plan_idle=True)
    assert submit(r.client)["id"] == "c00001"
    assert len(idle_descendants()) == 1


def test_the_planner_plans_a_grid_once_and_each_campaign_gets_a_plan_of_its_own(monkeypatch):
    """The worker keeps the plans it made (a lab submits one grid for sample after sample): a grid asked
    again is a copy of the plan made first, equal to a fresh plan (pickled, bit for bit), and a campaign
    that changes its copy changes no other; another config or grid is planned anew; the oldest plan
    makes room for the newest."""
    import pickle

    import gonio.campaign as campaign
    from gonio.config import load_config
    from gonio.daemon.planner import PlanCache

    cfg, calls = load_config(), []
    plan_campaign = campaign.plan_campaign
    monkeypatch.setattr(campaign, "plan_campaign",
                        lambda grid, c: calls.append(grid) or plan_campaign(grid, c))
    plans = PlanCache(size=2)
    a, b = plans("iso:step=45", cfg), plans("iso:step=45", cfg)
    assert calls == ["iso:step=45"] and plans.planned == 1
    fresh = plan_campaign("iso:step=45", cfg)
    assert pickle.dumps(a) == pickle.dumps(b) == pickle.dumps(fresh)
    a.plan.theta_i[:] = -1.0
    a.meta["x"] = 1
    assert pickle.dumps(plans("iso:step=45", cfg)) == pickle.dumps(fresh)
    other = cfg.model_copy(update={"name": "another"})
    plans("iso:step=45", other)
    plans("iso:step=60", cfg)          # three kept in two places: the least recently used goes
    assert calls == ["iso:step=45", "iso:step=45", "iso:step=60"] and plans.planned == 3
    plans("iso:step=60", cfg)
    plans("iso:step=45", other)
    assert plans.planned == 3
    plans("iso:step=45", cfg)
    assert plans.planned == 4
    # Past its steps in all, the oldest plans go too (the newest is kept, however large).
    steps = len(plans("iso:step=60", cfg).plan.step_kind)
    small = PlanCache(size=8, max_steps=steps)
    small("iso:step=60", cfg)
    small("iso:step=45", cfg)                     # more steps than the budget: kept alone
    small("iso:step=45", cfg)
    small("iso:step=60", cfg)
    assert small.planned == 3


def test_a_daemon_given_plans_starts_its_planner_with_them(serve, tmp_path):
    """The plans a daemon is given (``plans``: those of the other daemons of a process, the tests') are
    the worker's first: a grid kept there is not planned again. Seen by a plan kept under another grid's
    name (iso:step=45's under iso:step=30: a grid a daemon would never plan so)."""
    from gonio.campaign import plan_campaign
    from gonio.config import load_config
    from gonio.daemon.planner import PlanCache

    cfg, plans = load_config(), PlanCache()
    coarse = plan_campaign("iso:step=45", cfg)
    plans.keep("iso:step=30", cfg, coarse)
    given = serve(plans=plans)
    assert submit(given.client, grid="iso:step=30")["steps"] == coarse.steps != 30
    fresh = serve(plans=None, data=tmp_path / "fresh")
    assert submit(fresh.client, grid="iso:step=30")["steps"] == 30       # planned by its worker


def test_a_planner_stopped_while_its_worker_starts_does_not_wait_for_it(monkeypatch):
    """A fresh fork server imports the planner for a second or more before the worker runs; a daemon
    stopped meanwhile (a SIGTERM as it starts) waited for that. stop() now returns while the worker is
    still starting, and the worker is killed once it has started."""
    import multiprocessing
    import threading

    import gonio.daemon.planner as planner_module
    from gonio.config import load_config
    from gonio.sim.materials.library import MaterialsFolder

    release, procs = threading.Event(), []

    class SlowStart:      # a worker whose start blocks, as on a fork server still importing
        def __init__(self, **kw):
            self.killed = False
            procs.append(self)

        def start(self):
            release.wait(3 * WAIT_S)

        def is_alive(self):
            return not self.killed

        def kill(self):
            self.killed = True

        def join(self, timeout=None):
            pass

    class Context:
        Process = SlowStart

        @staticmethod
        def Pipe():
            return multiprocessing.Pipe()

    monkeypatch.setattr(planner_module, "_context", Context)
    planner = planner_module.Planner(load_config(), MaterialsFolder(None))
    planner.start()
    wait_for(lambda: procs, "the worker's start")
    stopper = threading.Thread(target=planner.stop)
    stopper.start()
    try:
        stopper.join(WAIT_S)
        assert not stopper.is_alive()                             # returned with the start still blocked
    finally:
        release.set()
    planner._thread.join(WAIT_S)
    assert not planner._thread.is_alive() and procs[0].killed and len(procs) == 1
