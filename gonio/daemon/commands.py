"""The daemon's commands on the ``gonio`` command line: ``serve`` and its clients.

``gonio serve`` runs the daemon; ``gonio submit``, ``queue``, ``watch``, ``pause``, ``resume``,
``abort``, ``halt`` and ``fetch`` talk to it (:mod:`gonio.daemon.client`). ``gonio queue [ID]`` shows
the daemon's queue, or one campaign of it, as ``gonio status ID`` does (``gonio status DIR`` reads a
campaign folder directly). Each returns an exit status and prints one line on failure:
1 refused or failed, 2 a usage mistake (the daemon's 422 too: a field it finds invalid), 3 no daemon (or
lost it), 4 the campaign was (or may have been) accepted but the command lost sight of it: do not submit
it again (``gonio queue``, ``gonio watch ID``).
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

__all__ = ["add_parsers"]


def _hms(seconds) -> str:
    if seconds is None:
        return "?"
    s = int(round(seconds))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


def _fail(args, err) -> int:
    print(f"gonio {args.command}: {err}", file=sys.stderr)
    return err.code


def cmd_serve(args) -> int:
    from gonio.cli.common import refuse_emulated_placeholders
    from gonio.config import load_config
    from gonio.daemon.auth import check_bind, check_token
    from gonio.daemon.pacing import check_pace
    from gonio.daemon.planner import start_fork_server

    cfg = load_config(args.config)
    refuse_emulated_placeholders(cfg, args.config)
    if Path(args.data).exists() and not Path(args.data).is_dir():   # it said "gonio serve: FILE: File exists"
        raise ValueError(f"--data: {args.data} is a file, not a folder; give the folder that holds (or will "
                         "hold) the daemon's campaigns")
    pace = check_pace(args.pace)
    if not 0 <= args.port <= 65535:
        raise ValueError(f"--port: must be within [0, 65535], got {args.port}")
    if not 1 <= args.max_streams <= 1024:
        raise ValueError(f"--max-streams: must be within [1, 1024], got {args.max_streams}")
    token = args.token if args.token is not None else os.environ.get("GONIO_TOKEN")
    check_bind(args.host, check_token(token))   # as serve() does, before the fork server is started
    # The planner's fork server imports the planner while this process imports its web stack.
    start_fork_server()
    from gonio.daemon.server import serve, setup_logging

    setup_logging(json_lines=args.log_json)
    return serve(cfg, data=Path(args.data), host=args.host, port=args.port, token=token, pace=pace,
                 hold=args.hold, max_streams=args.max_streams, materials=args.materials,
                 allow_hosts=args.allow_host, halt_needs_token=args.halt_needs_token,
                 plan_idle=args.plan_priority == "idle",
                 announce=lambda line: print(line, file=sys.stderr, flush=True))


def _run(args, body) -> int:
    """``body(client)`` against the daemon at ``args.url``; a ClientError is one line on stderr."""
    from gonio.daemon.client import Client, ClientError  # httpx only for the client commands

    try:
        c = Client(args.url)
        try:
            return body(c)
        finally:
            c.close()
    except ClientError as err:
        return _fail(args, err)


def cmd_submit(args) -> int:
    request = {"grid": args.grid, "seed": args.seed}
    if args.material:
        request["material"] = args.material
    if args.sample:
        request["sample"] = args.sample
    detector = {k: v for k, v in (("exposure_s", args.exposure_s), ("frames", args.frames)) if v is not None}
    if detector:
        request["detector"] = detector

    def body(c) -> int:
        from gonio.daemon.client import ACCEPTED_UNKNOWN, NO_DAEMON, ClientError

        st = c.submit(request)
        print(st["id"])
        if st.get("found_in_queue"):
            print(f"the daemon was slow to answer but accepted the campaign: it is {st['id']} in its queue",
                  file=sys.stderr)
        print(f"campaign {st['id']}: {st['state']}, {st['poses']} poses of {st['grid']} "
              f"({st['steps']} steps), about {_hms(st['eta_gantry_s'])} of gantry time", file=sys.stderr)
        if not args.watch:
            return 0
        try:
            return _watch(c, st["id"])
        except ClientError as err:
            if err.code != NO_DAEMON:
                raise
            raise ClientError(f"campaign {st['id']} was accepted, but {err}; follow it with `gonio watch "
                              f"{st['id']}` (do not submit it again)", code=ACCEPTED_UNKNOWN) from None

    return _run(args, body)


def cmd_queue(args) -> int:
    def body(c) -> int:
        if args.id:
            st = c.campaign(args.id)
            if args.json:
                print(json.dumps(st, indent=2))
                return 0
            print(f"{st['id']}: {st['state']}")
            print(f"  {st['material'] or st['sample']} on {st['gantry']}, grid {st['grid']}, "
                  f"seed {st['seed']}")
            print(f"  progress: {st['steps_done']}/{st['steps']} steps ({100 * st['progress']:.1f} %), "
                  f"campaign time {_hms(st['campaign_s'])}")
            if st["steps_done"] < st["steps"] and st["state"] != "aborted":
                eta = f"{_hms(st['eta_wall_s'])} wall, " if st["eta_wall_s"] is not None else ""
                print(f"  ETA: {eta}about {_hms(st['eta_gantry_s'])} of gantry time left")
            if st.get("ended_short"):
                print(f"  ended short of its budget: {st['ended_short']}")
            for key in ("latched_fault", "last_fault", "error"):
                if st[key]:
                    print(f"  {key.replace('_', ' ')}: {st[key]}")
            return 0
        q = c.campaigns()
        if args.json:
            print(json.dumps(q, indent=2))
            return 0
        if not q["campaigns"]:
            print("no campaigns (submit one with `gonio submit`)")
        for st in q["campaigns"]:
            print(f"{st['id']}  {st['state']:<9} {st['steps_done']:>7}/{st['steps']:<7} "
                  f"{100 * st['progress']:5.1f} %  {st['grid']:<16} {st['material'] or st['sample']}")
        return 0

    return _run(args, body)


def _watch(c, cid: str) -> int:
    """Follow ``cid``'s event stream with a progress bar until it ends; 0 when done, 1 when aborted or
    when the daemon could not run it (``failed``: nothing happens until an operator resumes it)."""
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    console = Console(stderr=True, highlight=False)
    st = c.campaign(cid)
    total, done = st["steps"], st["steps_done"]
    final = None
    if console.is_terminal:
        progress = Progress(TextColumn(cid), BarColumn(), MofNCompleteColumn(),
                            TextColumn("{task.fields[state]}"), TimeElapsedColumn(), console=console)
        task = progress.add_task(cid, total=total, completed=done, state=st["state"])
        with progress:
            for event, _, data in c.events(cid):
                if event == "measurement":
                    progress.update(task, completed=data["done"])
                elif event == "state":
                    progress.update(task, state=data["state"])
                    if data["state"] == "failed":
                        progress.console.print(data["message"], markup=False)
                        final = "failed"
                        break
                elif event == "fault":
                    progress.console.print(f"fault: {data['message']}", markup=False)
                elif event == "end":
                    final = data["state"]
    else:
        last = 0.0
        for event, _, data in c.events(cid):
            if event == "measurement":
                now = time.monotonic()
                if now - last >= 5.0 or data["done"] == data["steps"]:
                    last = now
                    print(f"{cid}: {data['done']}/{data['steps']} steps "
                          f"({100 * data['done'] / data['steps']:.0f} %)", file=sys.stderr, flush=True)
            elif event in ("state", "fault"):
                print(f"{cid}: {data['state'] or event}: {data['message']}", file=sys.stderr, flush=True)
                if event == "state" and data["state"] == "failed":
                    final = "failed"
                    break
            elif event == "end":
                final = data["state"]
    print(f"campaign {cid}: {final}" + (f" (`gonio resume {cid}` tries again)" if final == "failed" else ""),
          file=sys.stderr)
    return 0 if final == "done" else 1


def cmd_watch(args) -> int:
    return _run(args, lambda c: _watch(c, args.id))


def cmd_control(args) -> int:
    """pause, resume, abort (a campaign) and halt (the gantry)."""
    def body(c) -> int:
        if args.command == "halt":
            r = c.halt()
        elif args.command == "resume" and args.clear_fault:
            r = c.action(args.id, "resume", clear_fault="true")
        else:
            r = c.action(args.id, args.command)
        # the state once: "c00002: pausing: the step in flight finishes, ..." (not "pausing: pausing: ...")
        print(f"{r['id'] or 'gantry'}: {r['state']}: {r['message'].removeprefix(r['state'] + ': ')}")
        return 0

    return _run(args, body)


def cmd_fetch(args) -> int:
    from gonio.cli.common import writable_out

    out = Path(args.out)
    if out.is_dir():
        raise ValueError(f"--out: {out} is a folder; give a file name, e.g. {out / (args.id + '-brdf.h5')}")
    out = writable_out(args.out, force=args.force)   # an existing file is replaced only with --force

    def body(c) -> int:
        n = c.fetch(args.id, out)
        print(f"wrote {out} ({n} bytes)")
        return 0

    return _run(args, body)


def add_parsers(sub, fmt, seed_type) -> None:
    """The daemon's subcommands, added to the ``gonio`` parser's subparsers ``sub``."""
    sv = sub.add_parser("serve", formatter_class=fmt,
                        help="the daemon: one gantry, an HTTP API, event streams and a live web view")
    sv.add_argument("--config", default=None, help="gantry config: a TOML file or a shipped config's name "
                    "(default: sim, the simulated gantry)")
    sv.add_argument("--host", default="127.0.0.1", help="address to listen on; beyond loopback only "
                    "with a token")
    sv.add_argument("--port", type=int, default=8765, help="port (0: any free port)")
    sv.add_argument("--data", default=os.environ.get("GONIO_DATA", "gonio-data"),
                    help="data folder: campaigns/<id>/ holds each campaign's journal and brdf.h5 "
                    "(GONIO_DATA)")
    sv.add_argument("--token", default=None, help="bearer token every write must carry, at least 16 "
                    "characters without whitespace (prefer GONIO_TOKEN: a command line is visible to other "
                    "users)")
    sv.add_argument("--materials", default=None, metavar="DIR",
                    help="folder whose files submitted campaigns may name as bsdf:NAME or merl:NAME "
                    "(without it, measured materials are refused; a request never names a path)")
    sv.add_argument("--allow-host", action="append", default=[], metavar="NAME[:PORT]",
                    help="another name the daemon answers to (its Host header), e.g. the gantry PC's name "
                    "on the network or a reverse proxy's; repeatable. Loopback names and the --host address "
                    "are always allowed; any other Host is refused (DNS rebinding); none by default")
    sv.add_argument("--halt-needs-token", action="store_true",
                    help="the emergency halt needs the token from loopback clients too (by default an "
                    "operator at the rig halts without one; behind a reverse proxy every client is loopback)")
    sv.add_argument("--pace", type=float, default=0.02,
                    help="simulated gantry: real seconds per gantry second (0: as fast as it computes)")
    sv.add_argument("--hold", action="store_true",
                    help="hold the campaigns that were running when the daemon stopped paused, not "
                    "resume them")
    sv.add_argument("--plan-priority", choices=("idle", "normal"), default="idle",
                    help="CPU priority of the worker that plans submitted campaigns: idle (the default: it "
                    "takes only CPU time nothing else wants, so the running campaign comes first) or normal "
                    "(a machine whose other work is no more urgent than the planning, e.g. a test suite's)")
    sv.add_argument("--max-streams", type=int, default=16, help="event-stream clients served at once")
    sv.add_argument("--log-json", action="store_true", help="log one JSON object per line")
    sv.set_defaults(func=cmd_serve)

    def client_parser(name: str, help_: str, func, with_id: bool = True):
        p = sub.add_parser(name, formatter_class=fmt, help=help_)
        if with_id:
            p.add_argument("id", metavar="ID", help="campaign id, e.g. c00001")
        p.add_argument("--url", default=None, help="the daemon (default: GONIO_URL, else "
                       "http://127.0.0.1:8765); writes carry GONIO_TOKEN")
        p.set_defaults(func=func)
        return p

    p = client_parser("submit", "submit a campaign to the daemon's queue (prints its id)", cmd_submit, False)
    p.add_argument("material", nargs="?", default=None, help="MATERIAL (simulated detector)")
    p.add_argument("--grid", required=True, help="GRID, e.g. iso:step=10")
    p.add_argument("--sample", default=None, help="name of the sample (real detector)")
    p.add_argument("--seed", type=seed_type, default=0, help="seed of simulated devices' random numbers")
    p.add_argument("--exposure-s", type=float, default=None, help="detector exposure per frame (s)")
    p.add_argument("--frames", type=int, default=None, help="detector frames per reading")
    p.add_argument("--watch", action="store_true", help="then follow it with a progress bar")
    p = client_parser("queue", "the daemon's queue, or one campaign's state, progress and ETA (client form "
                      "of `gonio status`)", cmd_queue, False)
    p.add_argument("id", metavar="ID", nargs="?", default=None, help="one campaign")
    p.add_argument("--json", action="store_true", help="JSON")
    client_parser("watch", "follow a campaign live (progress bar fed by its event stream)", cmd_watch)
    client_parser("pause", "pause a campaign: the step in flight finishes, then the gantry parks",
                  cmd_control)
    p = client_parser("resume", "resume a paused, halted or faulted campaign", cmd_control)
    p.add_argument("--clear-fault", action="store_true",
                   help="clear its latched fault (after fixing the cause)")
    client_parser("abort", "abort a campaign (final)", cmd_control)
    client_parser("halt", "emergency stop: every axis stops now, mid-move too", cmd_control, False)
    p = client_parser("fetch", "download a finished campaign's brdf.h5", cmd_fetch)
    p.add_argument("--out", required=True, metavar="FILE", help="where to write it")
    p.add_argument("--force", action="store_true", help="replace --out if it exists")
