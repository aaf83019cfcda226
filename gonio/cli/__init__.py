"""The ``gonio`` command line: one subcommand per job, grouped by what they work on.

- :mod:`gonio.cli.campaigns`: ``plan``, ``config``, ``simulate``, ``run``, ``status``;
- :mod:`gonio.cli.results`: ``fit``, ``export``, ``plot``, ``report`` (a finished campaign);
- :mod:`gonio.cli.hardware`: ``emulate``, ``gantry``;
- :mod:`gonio.daemon.commands`: ``serve`` and its clients.

A user's mistake (a bad GRID, MATERIAL, config key, path or seed) is one line on stderr naming the field
or path and what is allowed, exit code 2, and nothing written. ``--debug`` shows the traceback of an
unexpected error.
"""

from __future__ import annotations

import argparse
import signal
import sys
from pathlib import Path

from gonio.cli.common import (
    Interrupted,
    UsageError,
    _DefaultsFormatter,
    _in_main_thread,
    _install_startup_handlers,
    _seed,
    _user_error,
)
from gonio.config import ConfigError

__all__ = ["main", "build_parser"]


def build_parser() -> argparse.ArgumentParser:
    from gonio.campaign import software_version

    fmt = _DefaultsFormatter
    p = argparse.ArgumentParser(prog="gonio", formatter_class=fmt,
                                description="Control and acquisition for gonio-reflectometers.")
    p.add_argument("--version", action="version", version=f"gonio {software_version()}")
    p.add_argument("--debug", action="store_true", help="show the traceback of an unexpected error")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    from gonio.cli import batch, campaigns, hardware, results

    campaigns.add_parsers(sub, fmt)
    batch.add_parsers(sub, fmt)
    results.add_parsers(sub, fmt)
    hardware.add_parsers(sub, fmt)

    # The daemon and its clients: gonio serve, submit, queue, watch, pause, resume, abort, halt, fetch
    # (their cmd_* functions live in gonio.daemon.commands).
    from gonio.daemon.commands import add_parsers as add_daemon_parsers

    add_daemon_parsers(sub, fmt, _seed)
    return p


def main(argv: list[str] | None = None) -> int:
    from gonio.calibrate import CalibrationError
    from gonio.store import JournalError

    parser = build_parser()
    args = parser.parse_args(argv)
    main_thread = _in_main_thread()
    previous = (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) if main_thread else None
    _install_startup_handlers()
    try:
        return args.func(args)
    except (ConfigError, UsageError, JournalError, CalibrationError, ValueError, OSError) as err:
        if args.debug:
            raise
        print(f"gonio {args.command}: {_user_error(err)}", file=sys.stderr)
        return 2
    except Interrupted as err:
        out = getattr(args, "out", None)
        where = f"; the journal in {out} keeps every committed step: run the same command to resume" \
            if out and Path(out, "campaign.sqlite").exists() else "; nothing was written"
        print(f"gonio {args.command}: interrupted ({err}){where}", file=sys.stderr)
        return 130
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous[0])
            signal.signal(signal.SIGTERM, previous[1])
