"""Submit a campaign to the daemon and follow its events until it ends, then fetch its brdf.h5.

    python examples/daemon_events.py              a daemon of its own (simulated gantry, any free port)
    python examples/daemon_events.py --url URL    the daemon at URL (`gonio serve`; GONIO_TOKEN for writes)

The client is `gonio.daemon.client.Client`, what the `gonio submit|watch|fetch` commands use. Events
(server-sent, resumable with Last-Event-ID) are `measurement` (each committed reading, with the
progress it makes), `state`, `fault`, `log` and `end`. Leaves runs/daemon-events/brdf.h5.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
from pathlib import Path

from gonio.daemon.client import Client

OUT = Path("runs/daemon-events")
REQUEST = {"material": "ggx:alpha=0.2,metal=gold", "grid": "iso:step=30", "seed": 1}


@contextlib.contextmanager
def own_daemon(data: Path):
    """A daemon served from a thread of this process on a free loopback port (stopped on exit)."""
    from gonio.daemon.planner import start_fork_server

    start_fork_server()   # the planner's worker process imports the planner while this one imports the rest
    from gonio.config import load_config
    from gonio.daemon.server import build_daemon, start_in_thread

    # Its planner at this process's priority: nothing else runs on this daemon for it to yield to (at idle
    # priority, on a machine busy with other work, the submission waited for a core to fall idle).
    running = start_in_thread(build_daemon(load_config(), data, pace=0.0, plan_idle=False))
    try:
        yield running.url
    finally:
        running.stop()


def follow(url: str) -> int:
    client = Client(url)
    try:
        st = client.submit(REQUEST)
        cid = st["id"]
        print(f"submitted {cid}: {st['poses']} poses of {st['grid']}, {st['steps']} steps")
        final = None
        for event, _, data in client.events(cid):
            if event == "measurement" and (data["done"] % 10 == 0 or data["done"] == data["steps"]):
                print(f"  {data['done']}/{data['steps']} {data['kind']} at θi {data['theta_i_deg']:.0f}°, "
                      f"θo {data['theta_o_deg']:.0f}°: signal {data['signal'][0]:.4g}")
            elif event in ("state", "fault"):
                print(f"  {event}: {data['state'] or ''} {data['message']}")
            elif event == "end":
                final = data["state"]
        print(f"{cid}: {final}")
        if final != "done":
            return 1
        n = client.fetch(cid, OUT / "brdf.h5")
        print(f"wrote {OUT / 'brdf.h5'} ({n} bytes)")
        return 0
    finally:
        client.close()


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--url", default=None, help="a running daemon (default: start one in this process)")
    args = p.parse_args(argv)
    OUT.mkdir(parents=True, exist_ok=True)
    if args.url:
        return follow(args.url)
    with own_daemon(OUT / "data") as url:
        return follow(url)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
