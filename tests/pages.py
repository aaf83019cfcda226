"""Running the command blocks of README.md and of each page of docs/ as written (tests/test_readme.py),
and starting the pages that wait in real time early, beside the other tests.

A block is a fenced block whose info string starts with ``bash`` (or ``sh``) or ``python``; the others
(``toml``, ``text``) are not commands. Words after the language say how a person runs it:

- ``second-terminal ready="TEXT"``: a command that keeps running (the emulators, the daemon); the run
  starts it in the background, as the page says to in a second terminal, and goes on once it has
  printed TEXT; it is stopped with Ctrl-C (SIGINT) at the end of the page, the last started first.
- ``runs-the-tests``: ``make test``, which runs tests/test_readme.py: not run.

Each page runs in a fresh copy of the repository with its own ``.venv`` that points at this environment
(``bin`` is a link to this environment's, the set-up's stamps are in place), so ``make demo`` runs its
campaign as written without installing anything again; the set-up itself is covered by
tests/test_setup.py. Docs pages run with the environment activated, as the README leaves a shell
(`source .venv/bin/activate`).

Early start. The pages that start ``gonio emulate`` or ``gonio serve`` in a second terminal (README.md,
docs/measure.md, docs/daemon.md) wait most of their time: on servos that move in real time, on a daemon
whose simulated gantry keeps the default pace and whose planner runs at idle priority (on a machine
whose every core runs tests, it plans only when one waits). They run side by side, and under
pytest-xdist the first worker to finish collecting starts them in a background thread
(:func:`start_early`) while both workers go on with other tests; their test, put last in the order
(tests/conftest.py), then only collects the outcome (:func:`early_outcome`), wherever it runs. The
starter holds an exclusive ``flock`` on a file for as long as the pages run and the test takes a shared
one, so it waits without polling and a starter that died releases it (the test then fails saying so).
The starter's worker waits for its runs before it leaves (:func:`join_early`). Without xdist the test
runs its pages itself.
"""

from __future__ import annotations

import fcntl
import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
import threading
import traceback
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PAGES = ["README.md", *sorted(str(p.relative_to(ROOT)) for p in (ROOT / "docs").glob("*.md"))]
FENCE = re.compile(r"^```([^\n]*)\n(.*?)^```[ \t]*$", re.S | re.M)
#: How long one page may run (s) before it counts as failed.
PAGE_TIMEOUT_S = 900


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
            # The log exists before tail follows it: tail -F polls once a second for a file missing
            # when it starts (1-2 s late if the background subshell has not opened it yet).
            lines += [f": > {log}", f"( {body} ) >> {log} 2>&1 &", "background+=($!)",
                      # wait (bounded) until it prints its ready line, or fail showing what it printed
                      f"if ! timeout 120 grep -q -m1 -F {shlex.quote(ready)} <(tail -n +1 -F {log}); then "
                      f"cat {log} >&2; exit 1; fi"]
        else:
            lines.append(body)
    return "\n".join(lines) + "\n"


#: The commands that keep running in a second terminal and make a page wait in real time.
REAL_TIME = ("gonio emulate", "gonio serve")


def waits_in_real_time(page: str) -> bool:
    """Whether ``page`` starts ``gonio emulate`` (servos that move in real time) or ``gonio serve`` (a
    daemon at the default pace) in a second terminal."""
    return any("second-terminal" in options and any(cmd in text for cmd in REAL_TIME)
               for _, _, options, text in blocks(page))


def page_groups() -> list[tuple[str, ...]]:
    """The pages with command blocks, each alone, except those that wait in real time: they make one
    group whose pages run side by side (each in its own copy, with its own emulators or daemon), so that
    their waits overlap."""
    pages = [p for p in PAGES if blocks(p)]
    real_time = tuple(p for p in pages if waits_in_real_time(p))
    return ([real_time] if real_time else []) + [(p,) for p in pages if p not in real_time]


def early_groups() -> list[tuple[str, ...]]:
    """The groups started early under pytest-xdist: those whose pages wait in real time."""
    return [g for g in page_groups() if any(waits_in_real_time(p) for p in g)]


def group_id(group: tuple[str, ...]) -> str:
    """The test id of a group of pages (``README.md+docs/measure.md``)."""
    return "+".join(group)


def run_page(page: str, folder: Path) -> str | None:
    """Runs ``page``'s blocks in a fresh copy at ``folder``: None if they all ran, else what failed."""
    folder = _fresh_copy(folder)
    env = {k: v for k, v in os.environ.items() if k not in ("VIRTUAL_ENV", "PYTHONPATH", "GONIO_URL",
                                                             "GONIO_TOKEN", "GONIO_DATA")}
    env["PATH"] = os.pathsep.join(p for p in env.get("PATH", "").split(os.pathsep)
                                  if not p.startswith(sys.prefix))
    try:
        r = subprocess.run(["bash", "-c", script(page, activated=page != "README.md")], cwd=folder, env=env,
                           capture_output=True, text=True, timeout=PAGE_TIMEOUT_S)
    except subprocess.TimeoutExpired as e:
        return f"{page}: ran past {PAGE_TIMEOUT_S} s\n{e.stderr[-6000:] if e.stderr else ''}"
    if r.returncode != 0:
        return (f"{page}: a block failed (the last '###' line names it)\n"
                f"{r.stdout[-3000:]}\n{r.stderr[-6000:]}")
    if "Traceback" in r.stderr:
        return f"{page}: a traceback\n{r.stderr[-6000:]}"
    return None


def run_group(group: tuple[str, ...], folder: Path) -> list[str | None]:
    """Runs the pages of ``group`` side by side, each in its own copy under ``folder``: their outcomes."""
    with ThreadPoolExecutor(len(group)) as pool:
        return list(pool.map(lambda page: run_page(page, folder / page.replace("/", "-")), group))


# -- early start ---------------------------------------------------------------------------------------

_early: dict[tuple[str, ...], threading.Thread] = {}


def early_folder(group: tuple[str, ...]) -> Path | None:
    """Where this pytest-xdist run starts ``group`` early (None outside xdist)."""
    uid = os.environ.get("PYTEST_XDIST_TESTRUNUID")
    if not uid or not re.fullmatch(r"[0-9a-f]+", uid):
        return None
    return Path(tempfile.gettempdir()) / f"gonio-pages-{uid}" / group_id(group).replace("/", "-")


def start_early(group: tuple[str, ...]) -> bool:
    """Starts ``group``'s pages in a background thread unless another worker of this run did: whether
    this call started them."""
    folder = early_folder(group)
    if folder is None:
        return False
    folder.mkdir(parents=True, exist_ok=True)
    fd, held = tempfile.mkstemp(dir=folder, prefix="lock-")
    fcntl.flock(fd, fcntl.LOCK_EX)               # held from before the lock file has its name
    try:
        os.link(held, folder / "running.lock")   # only the first worker of the run names it
    except FileExistsError:
        os.close(fd)
        os.unlink(held)
        return False
    os.unlink(held)

    def run():
        outcome: list[str | None] = [f"the early run of {group_id(group)} wrote no outcome"]
        try:
            outcome = run_group(group, folder)
        except BaseException:  # noqa: BLE001 - whatever happened is the test's failure to report
            outcome = [f"the early run of {group_id(group)} raised\n{traceback.format_exc()}"]
        finally:
            try:
                tmp = folder / "outcome.json.tmp"
                tmp.write_text(json.dumps(outcome), encoding="utf-8")
                os.replace(tmp, folder / "outcome.json")
            finally:
                os.close(fd)                     # releases the lock: the test reads the outcome

    t = threading.Thread(target=run, name=f"early {group_id(group)}")
    t.start()
    _early[group] = t
    return True


def early_outcome(group: tuple[str, ...]) -> list[str | None] | None:
    """The outcome of ``group`` started early by a worker of this run, waited for (None: not started)."""
    folder = early_folder(group)
    if folder is None or not (folder / "running.lock").exists():
        return None
    with open(folder / "running.lock", "rb") as lock:
        fcntl.flock(lock, fcntl.LOCK_SH)         # blocks while the starter runs the pages
    done = folder / "outcome.json"
    if not done.exists():
        return [f"the worker that started {group_id(group)} early stopped before its pages ended"]
    outcome = json.loads(done.read_text(encoding="utf-8"))
    if not any(outcome):
        shutil.rmtree(folder, ignore_errors=True)
        try:
            folder.parent.rmdir()
        except OSError:
            pass                                 # another group's folder is still there
    return outcome


def join_early(group: tuple[str, ...] | None = None) -> None:
    """Waits for the pages this worker started early (it must not leave while they run): ``group``'s
    alone, or every group's."""
    for g in [group] if group is not None else list(_early):
        t = _early.pop(g, None)
        if t is not None:
            t.join()
