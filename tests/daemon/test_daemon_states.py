"""The daemon's campaign states: the explicit table derived from the engine's state (no daemon needed)."""

from __future__ import annotations

import pytest

from gonio.daemon.states import FINAL, HELD, IN_WORKER, STATES, CampaignView, campaign_state
from gonio.runner import State


def test_every_engine_state_has_a_daemon_state_in_the_worker_and_held():
    assert set(IN_WORKER) == {None, *State}
    assert set(IN_WORKER.values()) <= set(STATES) and set(HELD.values()) <= set(STATES)
    assert set(HELD) == {None, *(s for s in State if s != State.ABORTED)}
    assert FINAL <= set(STATES)


@pytest.mark.parametrize(("engine", "want"), [
    (None, "starting"), (State.IDLE, "starting"), (State.RUNNING, "running"), (State.PAUSING, "pausing"),
    (State.PAUSED, "pausing"), (State.HALTED, "halted"), (State.FAULTED, "faulted"),
    (State.DONE, "finishing"), (State.ABORTED, "aborting")])
def test_in_the_worker_the_state_is_the_engines(engine, want):
    assert campaign_state(CampaignView(in_worker=True, engine=engine)) == want


@pytest.mark.parametrize(("view", "want"), [
    (CampaignView(journal=False), "creating"),
    (CampaignView(journal=False, error=True), "failed"),
    (CampaignView(last="aborted", intent="run"), "aborted"),
    (CampaignView(last="done", brdf=True), "done"),
    (CampaignView(last="done", brdf=False, intent="run"), "queued"),    # brdf.h5 still to write
    (CampaignView(last=None, intent="run"), "queued"),
    (CampaignView(last="faulted", latched=True, intent="run"), "faulted"),
    (CampaignView(last="faulted", latched=True, intent="run", clear_fault=True), "queued"),
    (CampaignView(last="running", intent="hold", error=True), "failed"),
    (CampaignView(last="running", intent="hold"), "paused"),             # stopped with the daemon, held
    (CampaignView(last="pausing", intent="hold"), "paused"),
    (CampaignView(last="halted", intent="hold"), "halted"),
    (CampaignView(last="paused", intent="hold", latched=True), "faulted"),
])
def test_out_of_the_worker_the_state_comes_from_the_journal_and_the_intent(view, want):
    assert campaign_state(view) == want
