"""Every command block of README.md and of each page of docs/ runs as written, in order, on a fresh copy
of the repository, as a new user would run them (how: tests/pages.py).

The pages that start ``gonio emulate`` or ``gonio serve`` wait in real time; they run side by side in one
test, each in its own copy, and under pytest-xdist they start early, beside the other tests
(tests/pages.py, "Early start").
"""

from __future__ import annotations

import re

import pytest
from pages import PAGES, ROOT, blocks, early_groups, early_outcome, group_id, page_groups, run_group

pytestmark = pytest.mark.slow
#: About how long a page's blocks run alone (s), where it is among the longest tests of the suite: the
#: order in which ``make test`` starts them (tests/conftest.py); the other pages take 10-30 s. A group
#: started early goes last instead (``slow(last=True)``): by then its pages have run.
SECONDS = {"docs/batch.md": 40}


def _mark(group):
    if group in early_groups():
        return pytest.mark.slow(last=True)
    return pytest.mark.slow(seconds=max(SECONDS.get(p, 20) for p in group))


@pytest.mark.parametrize("pages", [pytest.param(g, id=group_id(g), marks=_mark(g)) for g in page_groups()])
def test_every_command_block_runs_as_written(pages, tmp_path):
    failures = early_outcome(pages)
    if failures is None:         # not started early: run here
        failures = run_group(pages, tmp_path)
    assert not any(failures), "\n\n".join(f for f in failures if f)


def test_the_pages_that_wait_in_real_time_run_side_by_side_and_every_page_runs():
    groups = page_groups()
    assert groups[0] == ("README.md", "docs/daemon.md", "docs/measure.md")
    assert early_groups() == [groups[0]]
    assert sorted(p for g in groups for p in g) == sorted(p for p in PAGES if blocks(p))


def test_the_readme_runs_make_demo_and_explains_gonio_emulate():
    texts = [b[3] for b in blocks("README.md")]
    assert any(t.strip().startswith("make demo") for t in texts)
    assert any("gonio emulate --config emulated-" in t for t in texts)
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert "DESIGN.md" not in readme   # it is not in the repository
    for link in re.findall(r"\]\(([^)#]+)\)", readme):
        assert (ROOT / link).exists(), link


def test_every_source_file_and_folder_the_pages_name_is_in_the_repository():
    """docs/simulation.md sent a reader to `gonio/sim/materials/catalog.py`: the installed package's path,
    not the repository's (`sim/` is mapped into gonio, docs/layout.md)."""
    named = re.compile(r"`((?:gonio|sim|drivers|tests|tools|config|examples)/[\w./-]*(?:\.\w+|/))`")
    missing = [f"{page}: {path}" for page in PAGES
               for path in named.findall((ROOT / page).read_text(encoding="utf-8"))
               if not (ROOT / path).exists()]
    assert missing == []


def test_the_shipped_configs_table_of_docs_measure_names_every_shipped_config():
    """`gonio config list` showed emulated-two-arm-scpi, which the table a newcomer reads did not."""
    from gonio.config import packaged_configs

    page = (ROOT / "docs" / "measure.md").read_text(encoding="utf-8")
    table = page[page.index("| shipped config | what |"):]
    first_cells = [row.split("|")[1] for row in table[:table.index("\n\n")].splitlines()[2:]]
    listed = {name for cell in first_cells for name in re.findall(r"`([\w-]+)`", cell)}
    assert listed == set(packaged_configs())


def test_the_brdf_h5_table_of_docs_export_lists_every_variable_of_the_file(tmp_path, capsys):
    """The layout table of docs/export.md against a brdf.h5 the code writes (it was in no document)."""
    import h5py

    from gonio.cli import main

    out = tmp_path / "run"
    argv = ["simulate", "lambert:albedo=0.5", "--grid", "iso:step=45", "--out", str(out), "--quiet"]
    assert main(argv) == 0
    page = (ROOT / "docs" / "export.md").read_text(encoding="utf-8")
    table = page[page.index("| variable | dimensions |"):]
    rows = [line for line in table[:table.index("\n\n")].splitlines() if line.startswith("| `")]
    listed = {name for row in rows for name in re.findall(r"`(\w+)`", row.split("|")[1])}
    with h5py.File(out / "brdf.h5") as f:
        written = set(f["samples"])
        attrs = set(f.attrs)
    assert written <= listed and listed - written == {"wavelength"}   # spectrometer campaigns only
    for name in attrs:
        assert f"`{name}`" in page, name


def test_a_group_started_early_is_run_once_and_its_test_reads_what_failed(tmp_path, monkeypatch):
    import pages

    monkeypatch.setattr(pages.tempfile, "gettempdir", lambda: str(tmp_path))
    monkeypatch.setenv("PYTEST_XDIST_TESTRUNUID", "0123abcd")
    runs = []
    monkeypatch.setattr(pages, "run_group",
                        lambda group, folder: runs.append(group) or [None, "docs/x.md: boom"])
    group = ("README.md", "docs/x.md")
    assert pages.start_early(group) and not pages.start_early(group)   # the second worker does not
    assert pages.early_outcome(group) == [None, "docs/x.md: boom"]    # waits for the first's thread
    pages.join_early(group)      # this group's thread only: the worker's real early pages run on
    assert runs == [group]
    # a starter that died before its pages ended (its lock released, no outcome) is a failure, said
    folder = pages.early_folder(("docs/y.md",))
    folder.mkdir(parents=True)
    (folder / "running.lock").touch()
    assert "stopped before its pages ended" in pages.early_outcome(("docs/y.md",))[0]
    monkeypatch.delenv("PYTEST_XDIST_TESTRUNUID")
    assert pages.early_folder(group) is None and pages.early_outcome(group) is None
