"""Fixtures shared across the test folders."""

import gc
import os
import resource
import sys
import time

import numpy as np
import pytest
from brdf_samples import sampled
from jit_backends import backend_params

from gonio.jit import ENV_VAR, array_types


def pytest_collection_modifyitems(items):
    """The tests marked ``slow`` (whole campaigns, subprocesses, emulators on the wall clock) first, the
    longest first (``slow(seconds=S)``: about how long it runs alone; unsaid, 0), then the rest, each group
    in its collected order (a stable sort); last, the tests whose work started early (``slow(last=True)``:
    tests/pages.py). ``make test`` runs on every core (pytest-xdist, ``--dist load
    --maxschedchunk 2``): each worker is handed the next test or two of this order as it finishes, so the
    long tests are shared out as the workers come free and none is left alone at the end.

    Without ``--maxschedchunk``, ``--dist load`` hands each worker a consecutive eighth of the suite at the
    start (281 tests of 2254 on 2 workers): the first worker drew every slow test and ran 741 s of tests
    while the other ran 569 s. Not ``--dist loadgroup``/``loadscope``: they keep their units by test id,
    and the daemon's fuzz test gives every API operation the same id (schemathesis), so they would run one
    operation of 13."""
    def order(item):
        slow = item.get_closest_marker("slow")
        if slow is None:
            return (1, 0)
        if slow.kwargs.get("last"):   # started early, beside the others: collected at the end
            return (2, 0)
        return (0, -slow.kwargs.get("seconds", 0))

    items.sort(key=order)


#: The collector's first threshold in the test processes: a young collection every 10,000 net allocations,
#: not every 700 (Python's default). Each young collection may promote to the next, and every tenth of
#: those may start a full collection of the whole heap, which in a worker holding the collected suite and
#: the kept plans and campaigns (0.3-1 million objects) costs 0.2-1 s. With the default, the two
#: workers of `make test` spent 13.6 s of CPU in the collector (40 full collections, 11.6 s); with
#: this and the freeze below, 5.8 s (14 full ones). Cycles are still collected, a little later. Only
#: the test processes run so: the `gonio` commands they start keep Python's defaults.
GC_YOUNG_THRESHOLD = 10_000


def pytest_configure(config):
    gc.set_threshold(GC_YOUNG_THRESHOLD, *gc.get_threshold()[1:])


def pytest_collection_finish(session):
    """The collected suite (about 290,000 objects that live as long as the run) frozen out of the
    collector's full collections (``gc.freeze``, after one collection so that no garbage is frozen).
    Under pytest-xdist, the docs pages that wait on emulated servos start now, in the background of
    the first worker to get here, if their test is among those to run (tests/pages.py, "Early start")."""
    gc.collect()
    gc.freeze()
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        return
    names = {item.name for item in session.items if item.nodeid.split("::")[0].endswith("test_readme.py")}
    if not names:
        return
    import pages

    for group in pages.early_groups():
        if f"test_every_command_block_runs_as_written[{pages.group_id(group)}]" in names:
            pages.start_early(group)


def pytest_sessionfinish(session):
    """A worker that started pages early waits for them before it leaves."""
    if "pages" in sys.modules:
        sys.modules["pages"].join_early()


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    """With ``GONIO_TEST_CPU=FILE``: one line per test appended to FILE.<worker>: the wall seconds and the CPU
    seconds (user + system) of this process and of the subprocesses it waited for, set-up and tear-down
    included (tools/test_cpu.py sums them). Off by default."""
    log = os.environ.get("GONIO_TEST_CPU")
    if not log:
        yield
        return
    def cpu():
        s, c = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
        return s.ru_utime + s.ru_stime, c.ru_utime + c.ru_stime
    t0, (s0, c0) = time.perf_counter(), cpu()
    yield
    t1, (s1, c1) = time.perf_counter(), cpu()
    worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
    with open(f"{log}.{worker}", "a", encoding="utf-8") as f:
        f.write(f"{t1 - t0:.3f}\t{s1 - s0:.3f}\t{c1 - c0:.3f}\t{item.nodeid}\n")


@pytest.fixture
def make_sampled():
    """``sampled(spec, grid, theta_max_deg=85, rel_sd=0.01)``: a SampledBRDF from a material's own eval."""
    return sampled


@pytest.fixture(params=backend_params())
def backend(request, monkeypatch):
    """Each Dr.Jit backend in turn (CUDA skipped where Dr.Jit finds no device). ``GONIO_BACKEND`` is set to
    it for the test, so everything that resolves the default backend (simulated detectors, fits,
    materials evaluated from numpy, subprocesses) computes there."""
    monkeypatch.setenv(ENV_VAR, request.param)
    return request.param


@pytest.fixture
def jit(backend):
    """The Dr.Jit array types of each backend in turn (``jit.Float64``, ``jit.Array3f``, ``jit.PCG32``...)."""
    return array_types(backend)


@pytest.fixture(scope="session")
def planned():
    """``planned(grid, cfg, kin)``: ``build_plan(grid, cfg, kin)``, built once per session for tests that
    only read the plan (its arrays are read-only: a test that wrote into a shared plan would fail). A
    fine grid on the sample stage takes the planner 10 s or more."""
    from gonio.plan import build_plan

    plans = {}

    def plan(grid, cfg, kin):
        key = (grid, cfg.model_dump_json())
        if key not in plans:
            p = build_plan(grid, cfg, kin)
            for value in vars(p).values():
                if isinstance(value, np.ndarray):
                    value.flags.writeable = False
            plans[key] = p
        return plans[key]

    return plan
