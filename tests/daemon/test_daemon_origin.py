"""A web page in the operator's browser cannot drive the daemon: a real headless Chromium (Debian's, driven
by Playwright) on another origin sends cross-site form POSTs and ``no-cors`` fetches to halt, pause,
resume, abort and submit, and a page on a name re-bound to 127.0.0.1 (DNS rebinding) tries to read and
write same-origin. Every request reaches the daemon and is refused (403) while a campaign runs on,
untouched. Skipped where chromium is not installed."""

from __future__ import annotations

import json

from daemon_helpers import TOKEN, WAIT_S, submit, unpace, wait_for, wait_state
from test_daemon_web import pytestmark  # noqa: F401  (the skip when chromium is absent)

from gonio.store import JOURNAL_NAME, Journal

ATTACKS = ["/gantry/halt", "/campaigns/c00001/pause", "/campaigns/c00001/resume", "/campaigns/c00001/abort",
           "/campaigns"]
#: The encodings an HTML form can POST without a CORS preflight (multipart/form-data aside).
ENCTYPES = ["text/plain", "application/x-www-form-urlencoded"]


def _events(r) -> list[str]:
    j = Journal.open(r.daemon.queue.root / "c00001" / JOURNAL_NAME, readonly=True)
    try:
        return [e["kind"] for e in j.events()]
    finally:
        j.close()


def _page_at(browser, url: str, html: str):
    """A page whose document at ``url`` is ``html`` (served by the browser itself: the origin is
    ``url``'s, no server of ours is involved)."""
    page = browser.new_page()
    page.set_default_timeout(WAIT_S * 1000)
    page.route(url, lambda route: route.fulfill(status=200, content_type="text/html", body=html))
    seen = []
    page.on("response", lambda resp: seen.append((resp.request.method, resp.url, resp.status)))
    page.goto(url)
    return page, seen


def test_cross_site_forms_and_no_cors_fetches_are_refused_while_a_campaign_runs(serve, browser):
    r = serve(pace=0.5)
    submit(r.client, grid="iso:step=15")   # half a real second per gantry second: it outlasts the test
    wait_state(r.client, "c00001", "running")
    before = _events(r)
    port = r.url.rsplit(":", 1)[1]
    daemon = f"http://127.0.0.1:{port}"
    # Another site (attacker.test), and the same site on another port (127.0.0.1:1). Each page sends every
    # attack at once (two forms and a no-cors fetch for each path): each form into a frame of its own (a
    # submission into a frame still loading the last answer was sometimes never sent).
    for origin in ("http://attacker.test/", f"http://127.0.0.1:{int(port) % 60000 + 1}/"):
        page, seen = _page_at(browser, origin, '<html><body></body></html>')
        page.evaluate("""([urls, enctypes]) => {
            for (const url of urls) {
                for (const enctype of enctypes) {
                    const sink = document.createElement('iframe');
                    sink.name = 'sink' + Math.random(); document.body.appendChild(sink);
                    const f = document.createElement('form');
                    f.method = 'POST'; f.action = url; f.enctype = enctype; f.target = sink.name;
                    const i = document.createElement('input');
                    i.name = '{"grid": "iso:step=30", "material": "lambert:albedo=0.5", "x';
                    i.value = '"}';
                    f.appendChild(i); document.body.appendChild(f); f.submit();
                }
                fetch(url, {method: 'POST', mode: 'no-cors',
                    body: JSON.stringify({grid: 'iso:step=30', material: 'lambert:albedo=0.5'}),
                    headers: {'Content-Type': 'text/plain'}});
            } }""", [[f"{daemon}{path}" for path in ATTACKS], ENCTYPES])

        def answered(page=page, seen=seen):
            page.evaluate("0")   # Playwright hands its pending events (the responses) over in its calls
            posts = [u for m, u, s in seen if m == "POST"]
            return all(posts.count(f"{daemon}{path}") >= len(ENCTYPES) + 1 for path in ATTACKS)

        wait_for(answered, f"the attacks from {origin} to be answered")
        for path in ATTACKS:   # each form (one per enctype) and the fetch: refused, none let through
            statuses = [s for m, u, s in seen if m == "POST" and u == f"{daemon}{path}"]
            assert statuses == [403] * (len(ENCTYPES) + 1), (origin, path, seen)
        posts = [s for m, u, s in seen if m == "POST" and u.startswith(daemon)]
        assert posts and set(posts) == {403}, seen
        page.close()
    st = r.client.get("/campaigns/c00001").json()
    assert st["state"] == "running", st          # never paused, halted or aborted
    after = _events(r)
    assert after[:len(before)] == before and not {"pause", "halt", "park"} & set(after)
    assert [c["id"] for c in r.client.get("/campaigns").json()["campaigns"]] == ["c00001"]
    unpace(r.daemon)   # its park at once (pacing spends wall time only), then the abort
    r.client.post("/campaigns/c00001/abort").raise_for_status()


def test_a_rebinding_page_can_neither_read_nor_write(serve, browser):
    """DNS rebinding: a page of rebind.test:PORT, the name then pointed at 127.0.0.1, is same-origin
    with itself, so the browser lets it read what it fetches; the daemon refuses any Host not its own."""
    r = serve(token=TOKEN, pace=0.5)
    submit(r.client, grid="iso:step=15")   # half a real second per gantry second: it outlasts the test
    wait_state(r.client, "c00001", "running")
    port = r.url.rsplit(":", 1)[1]
    origin = f"http://rebind.test:{port}"
    page, seen = _page_at(browser, f"{origin}/attack.html", "<html><body>hi</body></html>")
    out = page.evaluate("""async () => {
        const out = {};
        for (const path of ['/campaigns', '/campaigns/c00001', '/campaigns/c00001/brdf', '/health',
                            '/gantry', '/campaigns/c00001/log', '/openapi.json']) {
            const r = await fetch(path); out['GET ' + path] = [r.status, await r.text()];
        }
        for (const path of ['/gantry/halt', '/campaigns/c00001/pause', '/campaigns/c00001/abort']) {
            const r = await fetch(path, {method: 'POST'});
            out['POST ' + path] = [r.status, await r.text()];
        }
        const r = await fetch('/campaigns', {method: 'POST',
            headers: {'Content-Type': 'application/json'},
            body: JSON.stringify({grid: 'iso:step=30', material: 'lambert:albedo=0.5'})});
        out['POST /campaigns'] = [r.status, await r.text()];
        return out; }""")
    page.close()
    assert len(out) == 11
    for what, (status, text) in out.items():
        assert status == 403, (what, status, text)
        assert json.loads(text) == {"detail": f"Host 'rebind.test:{port}' is not one of this daemon's names; "
                                              "add it with gonio serve --allow-host NAME"}, what
    assert r.client.get("/campaigns/c00001").json()["state"] == "running"
    assert [c["id"] for c in r.client.get("/campaigns").json()["campaigns"]] == ["c00001"]
    assert not {"pause", "halt"} & set(_events(r))
    unpace(r.daemon)   # its park at once (pacing spends wall time only), then the abort
    r.client.post("/campaigns/c00001/abort").raise_for_status()
