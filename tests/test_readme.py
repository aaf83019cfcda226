"""Every command block of README.md and of each page of docs/ runs as written, in order, on a fresh copy
of the repository, as a new user would run them.

A block is a fenced block whose info string starts with ``bash`` (or ``sh``) or ``python``; the others
(``toml``, ``text``) are not commands. Words after the language say how a person runs it:

- ``second-terminal ready="TEXT"``: a command that keeps running (the emulators, the daemon); the test
  starts it in the background, as the page says to in a second terminal, and goes on once it has
  printed TEXT; it is stopped with Ctrl-C (SIGINT) at the end of the page, the last started first.
- ``runs-the-tests``: ``make test``, which runs this file: not run here.

The copy gets its own ``.venv`` that points at this environment (``bin`` is a link to this environment's,
the set-up's stamps are in place), so ``make demo`` runs its campaign as written without installing
anything again; the set-up itself is covered by tests/test_setup.py. Docs pages run with the
environment activated, as the README leaves a shell (`source .venv/bin/activate`).

The pages that start ``gonio emulate`` wait on servos that move in real time; they run side by side in one
test, each in its own copy, so that their waits overlap.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PAGES = ["README.md", *sorted(str(p.relative_to(ROOT)) for p in (ROOT / "docs").glob("*.md"))]
FENCE = re.compile(r"^```([^\n]*)\n(.*?)^```[ \t]*$", re.S | re.M)
pytestmark = pytest.mark.slow
#: About how long a page's blocks run alone (s), where it is among the longest tests of the suite: the
#: order in which ``make test`` starts them (tests/conftest.py); the other pages take 10-30 s.
SECONDS = {"README.md": 80, "docs/measure.md": 60, "docs/batch.md": 40}


def blocks(page: str) -> list[tuple[int, str, dict, str]]:
    """(line, language, options, text) of each command block of ``page``, in order."""
    text = (ROOT / page).read_text(encoding="utf-8")
    out = []
    for m in FENCE.finditer(text):
        words = shlex.split(m.group(1))
        lang = words[0] if words else ""
        if lang not in ("bash", "sh", "python"):
            continue
        options = dict(w.split("=", 1) if "=" in w else (w, "") for w in words[1:])
        out.append((text.count("\n", 0, m.start()) + 1, lang, options, m.group(2)))
    return out


def _fresh_copy(dest: Path) -> Path:
    """The repository's files (as a clone has them) in ``dest``, with a .venv that is this environment."""
    ignore = shutil.ignore_patterns(".git", ".venv", "__pycache__", "*.egg-info", "build", "demo-out", "runs",
                                    "gonio-data", ".pytest_cache", ".hypothesis", ".benchmarks")
    shutil.copytree(ROOT, dest, ignore=ignore)
    venv = dest / ".venv"
    venv.mkdir()
    (venv / "bin").symlink_to(Path(sys.prefix) / "bin")
    for stamp in (".runtime-stamp", ".dev-stamp"):
        (venv / stamp).touch()           # newer than the copied pyproject.toml and tools/setup.sh
    return dest


def script(page: str, activated: bool) -> str:
    """A bash script running the page's blocks in order (see the module docstring)."""
    lines = ["set -euo pipefail", "background=()",
             # Ctrl-C in each second terminal, the last opened first, each stopped before the next: a
             # Dask worker whose scheduler stopped first logs a traceback of the lost connection.
             "stop() { for ((i=${#background[@]}-1; i>=0; i--)); do p=${background[i]};"
             " kill -INT \"$p\" 2>/dev/null || true; wait \"$p\" 2>/dev/null || true; done; }",
             "trap stop EXIT"]
    if activated:
        lines.append("source .venv/bin/activate")
    for k, (line, lang, options, text) in enumerate(blocks(page)):
        lines.append(f"echo '### {page}:{line}' >&2")
        if "runs-the-tests" in options:
            continue
        body = text if lang != "python" else f"python - <<'GONIO_PY_EOF'\n{text}GONIO_PY_EOF\n"
        if "second-terminal" in options:
            ready = options.get("ready")
            assert ready, f"{page}:{line}: a second-terminal block says what it prints when ready"
            log = f"second-terminal-{k}.log"
            lines += [f"( {body} ) > {log} 2>&1 &", "background+=($!)",
                      # wait (bounded) until it prints its ready line, or fail showing what it printed
                      f"if ! timeout 120 grep -q -m1 -F {shlex.quote(ready)} <(tail -n +1 -F {log}); then "
                      f"cat {log} >&2; exit 1; fi"]
        else:
            lines.append(body)
    return "\n".join(lines) + "\n"


def emulates(page: str) -> bool:
    """Whether ``page`` starts ``gonio emulate`` in a second terminal: its campaign then waits on servos
    that move in real time (README.md and docs/measure.md: about 50 s of their minute is waiting)."""
    return any("second-terminal" in options and "gonio emulate" in text
               for _, _, options, text in blocks(page))


def page_groups() -> list[tuple[str, ...]]:
    """The pages with command blocks, each alone, except those that drive emulated servos in real time:
    they make one group whose pages run side by side (each in its own copy, with its own emulators), so
    that their waits overlap instead of holding a test worker for a minute each."""
    pages = [p for p in PAGES if blocks(p)]
    real_time = tuple(p for p in pages if emulates(p))
    return ([real_time] if real_time else []) + [(p,) for p in pages if p not in real_time]


def run_page(page: str, folder: Path) -> str | None:
    """Runs ``page``'s blocks in a fresh copy at ``folder``: None if they all ran, else what failed."""
    folder = _fresh_copy(folder)
    env = {k: v for k, v in os.environ.items() if k not in ("VIRTUAL_ENV", "PYTHONPATH", "GONIO_URL",
                                                             "GONIO_TOKEN", "GONIO_DATA")}
    env["PATH"] = os.pathsep.join(p for p in env.get("PATH", "").split(os.pathsep)
                                  if not p.startswith(sys.prefix))
    r = subprocess.run(["bash", "-c", script(page, activated=page != "README.md")], cwd=folder, env=env,
                       capture_output=True, text=True, timeout=900)
    if r.returncode != 0:
        return (f"{page}: a block failed (the last '###' line names it)\n"
                f"{r.stdout[-3000:]}\n{r.stderr[-6000:]}")
    if "Traceback" in r.stderr:
        return f"{page}: a traceback\n{r.stderr[-6000:]}"
    return None


@pytest.mark.parametrize("pages", [pytest.param(g, id="+".join(g), marks=pytest.mark.slow(
                                       seconds=max(SECONDS.get(p, 20) for p in g))) for g in page_groups()])
def test_every_command_block_runs_as_written(pages, tmp_path):
    with ThreadPoolExecutor(len(pages)) as pool:
        failures = list(pool.map(lambda page: run_page(page, tmp_path / page.replace("/", "-")), pages))
    assert not any(failures), "\n\n".join(f for f in failures if f)


def test_the_pages_that_emulate_a_gantry_run_side_by_side_and_every_page_runs():
    groups = page_groups()
    assert groups[0] == ("README.md", "docs/measure.md")
    assert sorted(p for g in groups for p in g) == sorted(p for p in PAGES if blocks(p))


def test_the_readme_runs_make_demo_and_explains_gonio_emulate():
    texts = [b[3] for b in blocks("README.md")]
    assert any(t.strip().startswith("make demo") for t in texts)
    assert any("gonio emulate --config emulated-" in t for t in texts)
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert "DESIGN.md" not in readme   # it is not in the repository
    for link in re.findall(r"\]\(([^)#]+)\)", readme):
        assert (ROOT / link).exists(), link


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
