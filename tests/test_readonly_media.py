"""The commands that only read a campaign (status, plot, report, export, fit) leave its folder as they found
it and work where it cannot be written: a finished campaign archived on a read-only share, a DVD, a folder
the analysis account may not write.

The journal is SQLite in WAL mode, whose readers create ``-shm`` and ``-wal`` beside it unless they open it
``immutable`` (and cannot open it at all where those cannot be created), so a reader opens it immutable
when nobody writes it: its lock free, no commits waiting in the WAL. A reader of a running campaign stays a
live WAL reader (``gonio status`` while it runs; tests/test_kill_resume.py polls one), and one held open
when a writer comes becomes one (the daemon's event stream).

Read-only media: a read-only bind mount in a user and mount namespace of its own (``unshare``; no root
needed where unprivileged user namespaces are allowed, skipped elsewhere), the readers run in it (not
through ``/proc/PID/root``, which SQLite resolves to the writable folder outside).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from built_once import built_once

from gonio.campaign import CampaignLock
from gonio.cli import main
from gonio.store import JOURNAL_NAME, Journal, Measurement

#: Every command that only reads a finished campaign, as ``(name, arguments after the folder)``;
#: ``{out}`` is a folder elsewhere for what they write.
READERS = [
    ("status", ["--json"]),
    ("export", ["--format", "csv", "--out", "{out}/e.csv"]),
    ("fit", ["--model", "lambert", "--out", "{out}/f.json", "--quiet"]),
    ("plot", ["--kind", "polar", "--out", "{out}/p.png"]),
    ("report", ["--models", "lambert", "--out", "{out}/r.html"]),
]


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> Path:
    """A finished campaign, built once per run: the tests copy it."""
    def build(folder: Path) -> Path:
        assert main(["simulate", "lambert:albedo=0.5", "--grid", "iso:step=45", "--out", str(folder / "c"),
                     "--quiet"]) == 0
        return folder / "c"
    return built_once(tmp_path_factory, "readonly-finished", build)


def _files(folder: Path) -> dict[str, tuple[int, int]]:
    return {str(p.relative_to(folder)): (p.stat().st_size, p.stat().st_mtime_ns)
            for p in sorted(folder.rglob("*"))}


def _read(folder: Path, out: Path, capsys, readers=READERS) -> dict:
    """Run ``readers`` on ``folder`` in this process; each must succeed. The fit and the CSV export."""
    for name, args in readers:
        capsys.readouterr()
        assert main([name, str(folder), *(a.format(out=out) for a in args)]) == 0, capsys.readouterr().err
    return _outputs(out)


def _outputs(out: Path) -> dict:
    """The fit and the CSV export written in ``out``, less what differs from one folder to another."""
    fit = json.loads((out / "f.json").read_text())
    fit.pop("seconds"), fit.pop("source")     # the time it took, the folder's path
    rows = [ln for ln in (out / "e.csv").read_text().splitlines() if not ln.startswith("#")]  # not the folder
    return {"fit": fit, "csv": rows}


def test_reading_a_finished_campaign_leaves_its_folder_as_it_was(finished, tmp_path, capsys):
    folder = shutil.copytree(finished, tmp_path / "c")
    before = _files(folder)
    (tmp_path / "out").mkdir()
    for name, args in READERS:
        assert main([name, str(folder), *(a.format(out=tmp_path / "out") for a in args)]) == 0
        assert _files(folder) == before, f"gonio {name} left {set(_files(folder)) - set(before)}"


#: Run inside the namespace (SQLite resolves /proc/PID/root, a link to "/", to the path outside it, where the
#: folder is writable): the readers' journal reads, each path of them (plot reads it as export does:
#: gonio.cli.results.finished_campaign; the report as gonio.report.journal.campaign_facts, then brdf.h5).
INSIDE = """
import contextlib, io, json, sys
from pathlib import Path
from gonio.cli import main
from gonio.report.journal import campaign_facts
folder, out = sys.argv[1:]
status = io.StringIO()
with contextlib.redirect_stdout(status):
    codes = [main(["status", folder, "--json"])]
codes += [main(["export", folder, "--format", "csv", "--out", out + "/e.csv"]),
          main(["fit", folder, "--model", "lambert", "--quiet", "--out", out + "/f.json"])]
Path(out, "said.json").write_text(json.dumps({"codes": codes, "status": json.loads(status.getvalue()),
                                              "facts": campaign_facts(Path(folder))[0]["steps"]}))
"""


def test_a_finished_campaign_reads_on_read_only_media_as_anywhere(finished, tmp_path, capsys):
    """On a read-only bind mount of a copy (a user and mount namespace of its own, skipped where they are
    refused): the readers succeed, and fit and export give what they give on a writable copy (the fit fell
    back to independent samples where the journal, whose readings give the shared errors, was unread)."""
    from gonio.report.journal import campaign_facts

    if not shutil.which("unshare"):
        pytest.skip("unshare (util-linux) is not installed")
    folder = shutil.copytree(finished, tmp_path / "c")
    (tmp_path / "ro").mkdir()
    script = (f"mount --bind '{folder}' '{folder}' && mount -o remount,bind,ro '{folder}' || exit 99; "
              f"touch '{folder}/probe' 2>/dev/null && exit 98; exec \"$0\" -c \"$1\" \"$2\" \"$3\"")
    run = subprocess.run(["unshare", "--user", "--map-root-user", "--mount", "sh", "-c", script,
                          sys.executable, INSIDE, str(folder), str(tmp_path / "ro")],
                         capture_output=True, text=True, timeout=120)
    if run.returncode == 99 or "unshare failed" in run.stderr:
        pytest.skip(f"cannot bind-mount read-only in a user namespace here: {run.stderr[-300:]!r}")
    assert run.returncode == 0, run.stderr[-2000:]
    said = json.loads((tmp_path / "ro" / "said.json").read_text())
    assert said["codes"] == [0, 0, 0], run.stderr[-2000:]
    assert said["status"]["state"] == "done" and said["status"]["steps_done"] == said["status"]["steps"] > 0
    assert said["facts"] == campaign_facts(folder)[0]["steps"]
    assert sorted(p.name for p in folder.iterdir()) == sorted(p.name for p in finished.iterdir())
    (tmp_path / "rw").mkdir()
    here = _read(folder, tmp_path / "rw", capsys, [r for r in READERS if r[0] in ("export", "fit")])
    there = _outputs(tmp_path / "ro")
    assert there["fit"] == here["fit"] and there["csv"] == here["csv"]


# -- the journal's readers ----------------------------------------------------------------------------------

def _steps(n=4):
    ang = np.arange(n, dtype=float)
    return {"kind": np.zeros(n, np.int8), "pose": np.arange(n), "theta_i_deg": ang, "phi_i_deg": ang,
            "theta_o_deg": ang, "phi_o_deg": ang, "axes_deg": np.zeros((n, 4))}


def _m(step):
    return Measurement(step=step, kind=0, pose=step, commanded_deg=np.zeros(4), actual_deg=np.zeros(4),
                       angles_deg=np.zeros(4), clock_s=step, campaign_s=step, exposure_s=0.1, frames=1,
                       signal=np.ones(3), stderr=np.zeros(3))


def _campaign_journal(folder: Path) -> Path:
    """A journal in ``folder`` as a campaign has it (its lock file beside it, free), one step measured."""
    folder.mkdir()
    CampaignLock(folder).acquire().release()
    j = Journal.create(folder / JOURNAL_NAME, {}, _steps())
    j.commit_measurement(_m(0))
    j.close()
    return folder / JOURNAL_NAME


def test_a_reader_held_open_sees_what_a_writer_that_came_since_commits(tmp_path):
    path = _campaign_journal(tmp_path / "c")
    before = _files(path.parent)
    reader = Journal.open(path, readonly=True)
    assert reader.done_count() == 1 and _files(path.parent) == before   # nobody writes: nothing beside it
    lock = CampaignLock(path.parent).acquire()                            # a resume
    writer = Journal.open(path)
    writer.commit_measurement(_m(1))
    assert reader.done_count() == 2                                       # seen live, before any checkpoint
    writer.close()
    lock.release()
    assert reader.done_count() == 2
    reader.close()
    # A writer that takes no lock (the Journal API alone) and checkpoints into the file on closing
    Journal.open(path).close()      # the last connection checkpoints what the reader kept in the WAL
    assert not path.with_name(JOURNAL_NAME + "-wal").exists()
    reader = Journal.open(path, readonly=True)
    assert reader.done_count() == 2
    os.utime(path, ns=(0, 0))       # the file's times step on as the writer writes (within one clock tick)
    writer = Journal.open(path)
    writer.commit_measurement(_m(2))
    writer.close()
    assert reader.done_count() == 3
    reader.close()


def test_commits_a_killed_writer_left_in_the_wal_are_read(tmp_path):
    path = _campaign_journal(tmp_path / "c")
    lock = CampaignLock(path.parent).acquire()
    writer = Journal.open(path)
    writer.commit_measurement(_m(1))
    # What SIGKILL leaves: the WAL with the commit not checkpointed, the -shm, the lock free (the kernel's).
    crashed = tmp_path / "crashed"
    crashed.mkdir()
    for name in (JOURNAL_NAME, JOURNAL_NAME + "-wal", JOURNAL_NAME + "-shm", "campaign.lock"):
        shutil.copy(path.parent / name, crashed / name)
    writer.close()
    lock.release()
    reader = Journal.open(crashed / JOURNAL_NAME, readonly=True)
    assert reader.done_count() == 2
    reader.close()


def test_a_folder_named_with_uri_characters_is_read(tmp_path):
    folder = tmp_path / "run?1#a%20b"
    path = _campaign_journal(folder)
    reader = Journal.open(path, readonly=True)
    assert reader.done_count() == 1
    reader.close()


def test_a_writer_closing_under_a_live_reader_leaves_the_whole_journal_in_its_file(tmp_path):
    """SQLite checkpoints at the last connection's close only: a reader open then (``gonio status``, the
    daemon's event stream) left the last commits in the WAL, for every later reader to read live (and a copy
    of the journal file alone to miss)."""
    path = _campaign_journal(tmp_path / "c")
    lock = CampaignLock(path.parent).acquire()
    writer = Journal.open(path)
    reader = Journal.open(path, readonly=True)
    writer.commit_measurement(_m(1))
    assert reader.done_count() == 2
    writer.close()
    lock.release()
    reader.close()
    assert path.with_name(JOURNAL_NAME + "-wal").stat().st_size == 0
    alone = tmp_path / "alone"
    alone.mkdir()
    shutil.copy(path, alone / JOURNAL_NAME)
    copy = Journal.open(alone / JOURNAL_NAME, readonly=True)
    assert copy.done_count() == 2
    copy.close()
