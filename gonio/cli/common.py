"""What every gonio command shares: one-line user errors, signals, output, argument types."""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
import threading
from pathlib import Path

from gonio import SEED_MAX


class UsageError(ValueError):
    """A mistake in the command line: printed as one line, exit code 2."""


class Interrupted(BaseException):
    """SIGINT or SIGTERM before a campaign runs (start-up, planning, creating the journal)."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def hms(seconds: float) -> str:
    s = int(round(seconds))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


class Eta:
    """Wall-clock time left, from the pace of the steps measured since the first one of this run ended
    (that first step carries the start-up: compiling kernels, connecting, the first moves). ``None``
    until at least ``MIN_STEPS`` steps over ``MIN_S`` seconds after it give a pace: an ETA from one
    step read 102:34:40 for a 20-minute job.

    >>> eta = Eta(total=100)
    >>> eta.update(1, 30.0) is None           # the first step took 30 s (start-up)
    True
    >>> eta.update(4, 31.0) is None           # 3 steps since: not yet a pace
    True
    >>> round(eta.update(11, 32.0), 1)        # 10 steps in 2 s: 89 steps left take 17.8 s
    17.8
    >>> Eta(total=100).update(100, 0.5)       # every step measured: nothing left, whatever the pace
    0.0
    """

    MIN_STEPS = 5
    MIN_S = 1.0

    def __init__(self, total: int):
        self.total = total
        self._first: tuple[int, float] | None = None

    def update(self, done: int, now: float) -> float | None:
        if done >= self.total:
            return 0.0
        if self._first is None:
            self._first = (done, now)
            return None
        n, dt = done - self._first[0], now - self._first[1]
        if n < self.MIN_STEPS or dt < self.MIN_S:
            return None
        return (self.total - done) * dt / n

    @staticmethod
    def text(seconds: float | None) -> str:
        return "?" if seconds is None else hms(seconds)


def seed_type(text: str) -> int:
    rule = f"must be an integer in [0, {SEED_MAX}]"
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{rule}, got {text!r}") from None
    if not 0 <= value <= SEED_MAX:
        raise argparse.ArgumentTypeError(f"{rule}, got {value}")
    return value


def grid_arg(text: str):
    """``--grid`` parsed (:func:`gonio.plan.parse_grid`); a mistake in it is one line naming --grid."""
    from gonio.plan import parse_grid

    try:
        return parse_grid(text)
    except ValueError as err:
        raise UsageError(f"--grid: {err}") from None


#: What rich removes from printed text (its ``strip_control_codes``: BEL, BS, VT, FF, CR).
_CONTROL = dict.fromkeys((7, 8, 11, 12, 13))
#: The variables by which rich decides stderr is a terminal even where it is not a tty.
_TERMINAL_ENV = ("TTY_COMPATIBLE", "FORCE_COLOR")


class Out:
    """Messages to stderr: rich styles on a terminal, never rich markup (paths may hold ``[...]``) nor
    emoji codes (nor ``:name:``). Off a terminal (a pipe, a file, a test) each message is written as rich
    would write it there (tabs expanded, control codes dropped, no style) without importing rich (0.02 to
    0.04 s of CPU in every command); ``console`` makes rich's on first use."""

    def __init__(self, quiet: bool = False):
        self.quiet = quiet
        self._console = None

    @property
    def console(self):
        if self._console is None:
            from rich.console import Console

            self._console = Console(stderr=True, soft_wrap=True, highlight=False, emoji=False)
        return self._console

    def _plain(self) -> bool:
        """Whether rich would see no terminal (``rich.console.Console.is_terminal``), decided without
        importing it."""
        if self._console is not None or any(k in os.environ for k in _TERMINAL_ENV):
            return False
        try:
            return not sys.stderr.isatty()
        except (AttributeError, ValueError):   # no stream, or a closed one: rich sees no terminal either
            return True

    @property
    def is_terminal(self) -> bool:
        """Whether stderr is a terminal as rich decides it (live progress, spinners): rich is imported
        only where it may be one."""
        return not self._plain() and self.console.is_terminal

    def __call__(self, message: str, style: str | None = None) -> None:
        if self._plain():
            if sys.stderr is None:   # no stream at all (pythonw): rich writes nowhere either
                return
            sys.stderr.write(str(message).expandtabs(8).translate(_CONTROL) + "\n")
            sys.stderr.flush()
            return
        self.console.print(message, style=style, markup=False)


def not_empty(text: str, what: str = "file") -> str:
    """--out as typed; an empty one is refused (it would name the current folder)."""
    if not text.strip():
        raise UsageError(f"--out: empty; give a {what} name")
    return text


@contextlib.contextmanager
def planning(out: Out, what: str, show: bool):
    """A spinner with the time spent while ``what`` is planned (it may take a minute), on a terminal
    only (``show``: neither --quiet nor --json); it disappears once the plan is made."""
    if not (show and out.is_terminal):
        yield
        return
    from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    with Progress(SpinnerColumn(), TextColumn("{task.description}"), TimeElapsedColumn(), console=out.console,
                  transient=True) as progress:
        progress.add_task(f"planning {what}", total=None)
        yield


def creatable_folder(out: Path) -> Path:
    """--out where a folder is (or can be) made: its nearest existing ancestor is a writable folder."""
    probe = out
    while not probe.exists():
        probe = probe.parent
    if not probe.is_dir():
        raise UsageError(f"--out: {probe} is a file, so {out} cannot be a folder")
    if not os.access(probe, os.W_OK | os.X_OK):
        raise UsageError(f"--out: {probe} is not writable (permission denied); choose another folder")
    return out


def writable_out(text: str, *, folder: bool = False, force: bool = False) -> Path:
    """--out checked before any work: not empty, its folder exists and takes a file; an existing file
    (or, with ``folder``, a folder of files) is replaced only with ``force`` (``--force``)."""
    out = Path(not_empty(text, "folder" if folder else "file"))
    parent = out.parent if str(out.parent) else Path(".")
    if not parent.is_dir():
        raise UsageError(f"--out: folder {parent} does not exist; create it or choose another path")
    if out.is_dir() and not folder:
        raise UsageError(f"--out: {out} is a folder; give a file name")
    if out.exists() and folder and not out.is_dir():
        raise UsageError(f"--out: {out} is a file; this format writes a folder of files")
    if out.exists() and not force:
        raise UsageError(f"--out: {out} exists; choose another path, or add --force to replace it")
    probe = parent / f".{out.name}.{os.getpid()}.probe"
    try:
        probe.open("w").close()
        probe.unlink()
    except OSError as err:
        raise UsageError(f"--out: {out} cannot be written ({err.strerror or err}); choose another path") \
            from None
    return out


class command:  # noqa: N801 (used as a function: ``set_defaults(func=command("module:attr"))``)
    """A subcommand's function named by ``"module:attr"``, imported only when the command runs: building
    the parser (and ``--help``, ``--version``) imports nothing a command uses."""

    def __init__(self, target: str):
        self.target = target

    def __call__(self, args) -> int:
        from gonio.registry import Entry

        return Entry(self.target, self.target).load()(args)

    def __repr__(self) -> str:
        return f"command({self.target!r})"


def add_force(parser) -> None:
    """``--force``: the commands that write one --out file (or folder) replace an existing one only then."""
    parser.add_argument("--force", action="store_true", help="replace --out if it exists")


#: The port a shipped ``emulated-*`` config gives each serial bus: a placeholder that ``gonio emulate
#: --write-config FILE`` replaces with the pty its emulator listens on.
EMULATED_PORT = "emulated://"


def refuse_emulated_placeholders(cfg, config: str | None) -> None:
    """A config whose buses still name ``emulated://`` ports cannot be opened: one line saying what to run
    (before anything is planned or written)."""
    for name, bus in cfg.buses.items():
        port = getattr(bus, "port", None) or ""
        if port.startswith(EMULATED_PORT):
            shown = config or cfg.name
            raise UsageError(f"--config: {shown} reaches its devices through emulators (bus '{name}': port "
                             f"{port}); start them in another shell with `gonio emulate --config {shown} "
                             "--write-config emu.toml`, then pass --config emu.toml")


# -- the parser -----------------------------------------------------------------------------------
class Parser(argparse.ArgumentParser):
    """argparse's parser, with a mistake in the command line (a missing ``--out``, an unknown option, a
    bad choice) as every other user error is: one line on stderr naming the argument, exit code 2.
    argparse printed its usage block above the line; ``--help`` shows it. Subcommands' parsers are of
    this class too (``add_subparsers`` makes them of its parser's class)."""

    def error(self, message):
        self.exit(2, f"{self.prog}: {message}; `{self.prog} --help` shows every argument\n")

    def parse_args(self, args=None, namespace=None):
        """As argparse's, with arguments no parser took refused by the subcommand they were given to
        (``gonio simulate: unrecognized arguments: --sed 3``), not by ``gonio``."""
        namespace, extra = self.parse_known_args(args, namespace)
        if extra:
            self._innermost(namespace).error(f"unrecognized arguments: {' '.join(extra)}")
        return namespace

    def _innermost(self, namespace) -> argparse.ArgumentParser:
        for action in self._actions:   # the subcommands' action: its choices map names to parsers
            if isinstance(action.choices, dict):
                chosen = action.choices.get(getattr(namespace, action.dest, None))
                if isinstance(chosen, Parser):
                    return chosen._innermost(namespace)
        return self


class DefaultsFormatter(argparse.HelpFormatter):
    """Help that shows each option's default where it has a meaningful one (not for flags, required
    options, or where the text already says it)."""

    def _get_help_string(self, action):
        text = action.help or ""
        default = action.default
        if (default is None or default is False or default == argparse.SUPPRESS or "default" in text
                or action.required or not action.option_strings):
            return text
        return f"{text} (default: {default})"


class ReferenceFormatter(DefaultsFormatter, argparse.RawDescriptionHelpFormatter):
    """As :class:`DefaultsFormatter`, with the epilog (a reference generated from a registry) kept as it
    is laid out."""


# -- gonio status ---------------------------------------------------------------------------------
def lock_holder(folder: Path) -> int | None:
    """The pid holding the campaign's lock (running it now), or None."""
    from gonio.campaign import CampaignLock

    return CampaignLock.holder(folder)


def user_error(err: BaseException) -> str:
    if isinstance(err, OSError) and err.filename is not None:
        return f"{err.filename}: {err.strerror or err}"
    return str(err)


def _raise_interrupted(signum, frame):
    raise Interrupted(signum)


def in_main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


def install_startup_handlers() -> None:
    """Before and after a campaign runs, SIGINT and SIGTERM end the command cleanly (no traceback).
    Signal handlers belong to the main thread; called from another (a test, an embedding), nothing."""
    if in_main_thread():
        signal.signal(signal.SIGINT, _raise_interrupted)
        signal.signal(signal.SIGTERM, _raise_interrupted)


