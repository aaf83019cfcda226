"""The ``gonio`` command line: one subcommand per job, grouped by what they work on.

- :mod:`gonio.cli.parsers`: every subcommand's arguments and help (choices from :mod:`gonio.registries`);
- :mod:`gonio.cli.campaigns`: ``plan``, ``config``, ``simulate``, ``run``, ``status``;
- :mod:`gonio.cli.results`: ``fit``, ``export``, ``plot``, ``report`` (a finished campaign);
- :mod:`gonio.cli.hardware`: ``emulate``, ``gantry``;
- :mod:`gonio.daemon.commands`: ``serve`` and its clients.

A command's module is imported only when it runs, so ``gonio --version`` and ``gonio <command> --help``
start fast (tools/bench_startup.py). A user's mistake (a bad GRID, MATERIAL, config key, path or seed) is
one line on stderr naming the field or path and what is allowed, exit code 2, and nothing written.
``--debug`` shows the traceback of an unexpected error.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
from pathlib import Path

from gonio.cli.common import (
    DefaultsFormatter,
    Interrupted,
    Parser,
    UsageError,
    in_main_thread,
    install_startup_handlers,
    seed_type,
    user_error,
)

__all__ = ["main", "build_parser"]


class _Version(argparse.Action):
    """``--version``: the installed version, looked up only when asked for."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        from gonio import software_version

        print(f"gonio {software_version()}")
        parser.exit()


def build_parser() -> argparse.ArgumentParser:
    from gonio.cli.parsers import (
        add_batch_parsers,
        add_campaign_parsers,
        add_hardware_parsers,
        add_result_parsers,
    )
    from gonio.daemon.commands import add_parsers as add_daemon_parsers

    fmt = DefaultsFormatter
    p = Parser(prog="gonio", formatter_class=fmt,
               description="Control and acquisition for gonio-reflectometers.")
    p.add_argument("--version", action=_Version, help="show the version and exit")
    p.add_argument("--debug", action="store_true", help="show the traceback of an unexpected error")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    add_campaign_parsers(sub, fmt)
    add_batch_parsers(sub, fmt)
    add_result_parsers(sub, fmt)
    add_hardware_parsers(sub, fmt)
    # The daemon and its clients: gonio serve, submit, queue, watch, pause, resume, abort, halt, fetch
    # (their cmd_* functions live in gonio.daemon.commands).
    add_daemon_parsers(sub, fmt, seed_type)
    p.commands = tuple(sub.choices)  # every subcommand's name (tests, shell completion)
    return p


def _user_errors() -> tuple[type[BaseException], ...]:
    """What a command reports as one line (exit 2): evaluated only when a command raised, so that the
    journal's module is not imported before a command needs it."""
    from gonio.store import JournalError

    # ConfigError and CalibrationError are ValueErrors.
    return UsageError, JournalError, ValueError, OSError


def _kept(args, then: str) -> str:
    """What a command that stopped early leaves in its --out: a journal to resume, or nothing."""
    out = getattr(args, "out", None)
    if out and Path(out, "campaign.sqlite").exists():
        return f"; the journal in {out} keeps every committed step: {then} to resume"
    return "; nothing was written"


def _latched(out) -> bool:
    """Whether the journal in ``out`` latched the run's fault (it could, with the last free bytes)."""
    from gonio.store import JOURNAL_NAME, Journal

    if not out or not Path(out, JOURNAL_NAME).exists():
        return False
    try:
        journal = Journal.open(Path(out, JOURNAL_NAME), readonly=True)
    except Exception:   # unreadable: the resume will say what it finds
        return False
    try:
        return journal.latched_fault() is not None
    finally:
        journal.close()


def main(argv: list[str] | None = None) -> int:
    from gonio.registry import PluginError

    try:
        parser = build_parser()
    except PluginError as err:  # a plugin that cannot be imported: one line, before any command runs
        print(f"gonio: {err}", file=sys.stderr)
        return 2
    args = parser.parse_args(argv)
    main_thread = in_main_thread()
    previous = (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) if main_thread else None
    install_startup_handlers()
    try:
        code = args.func(args)
        sys.stdout.flush()   # a reader that left is found here, not by the interpreter's flush at exit
        return code
    except Interrupted as err:
        print(f"gonio {args.command}: interrupted ({err}){_kept(args, 'run the same command')}",
              file=sys.stderr)
        return 130
    except BrokenPipeError:
        # The reader of stdout left (`gonio plan --json | head`): end quietly as a Unix tool does, with
        # SIGPIPE's status, and let nothing flush into the closed pipe at exit.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 128 + signal.SIGPIPE
    except Exception as err:
        if args.debug:
            raise
        from gonio.store import disk_full_error

        if (full := disk_full_error(err)) is not None:   # an environment's failure, not the input's: exit 1
            then = "free some space, then run the same command" + \
                (" with --clear-fault" if _latched(getattr(args, "out", None)) else "")
            words = full.strerror if isinstance(full, OSError) and full.strerror else str(full)
            print(f"gonio {args.command}: the disk is full ({words}){_kept(args, then)}", file=sys.stderr)
            return 1
        if not isinstance(err, _user_errors()):
            raise
        print(f"gonio {args.command}: {user_error(err)}", file=sys.stderr)
        return 2
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous[0])
            signal.signal(signal.SIGTERM, previous[1])
