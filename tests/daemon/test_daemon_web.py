"""The live web view in a real headless browser (Debian's chromium, driven by Playwright): the queue,
the running campaign's progress, the pose sketch and a BRDF slice filling in; pause and resume buttons
with a token, and HALT without one. Skipped where chromium is not installed (tools/setup.sh installs it)."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from daemon_helpers import CHROMIUM, TOKEN, WAIT_S, submit, wait_for, wait_state

pytestmark = pytest.mark.skipif(not Path(CHROMIUM).exists(), reason="chromium is not installed "
                                "(apt-get install -y chromium; tools/setup.sh does it)")


@pytest.fixture
def page(browser):
    pg = browser.new_page(viewport={"width": 1200, "height": 800})
    pg.set_default_timeout(WAIT_S * 1000)
    try:
        yield pg
    finally:
        pg.context.close()


@pytest.mark.slow
def test_the_web_view_follows_a_campaign_and_its_buttons_work(serve, page, tmp_path):
    from PIL import Image

    # 10 ms of wall time per gantry second (~10 ms a step) until the daemon has measured the slice's first
    # five in-plane points (by step 51 of 310), then 50 ms (the ~250 steps left last ~12 s: the page's
    # checks and the pause land before the end, however far the page lags). iso:step=15's plan is kept by
    # the fixture; iso:step=10 (1168 steps) took 1.3 s of CPU to plan and ~1 s of pacing more.
    r = serve(token=TOKEN, pace=0.01)
    submit(r.client, grid="iso:step=15", material="ggx:alpha=0.2,metal=gold")
    page.goto(r.url + "/")
    page.wait_for_selector("#queue tbody tr[data-id='c00001']")
    wait_for(lambda: r.client.get("/campaigns/c00001").json()["steps_done"] >= 60, "60 steps measured")
    r.daemon.queue.gantry.clock.pace = 0.05
    assert page.is_disabled("#pause") and not page.is_disabled("#halt")    # no token typed yet: HALT is live
    page.fill("#token", TOKEN)
    page.wait_for_function("document.querySelector('#conn').textContent === 'live'")
    # The slice fills in as measurements arrive, and the sketch shows the pose.
    page.wait_for_function("parseInt(document.querySelector('#slice-label').textContent.slice(1)) >= 5")
    assert page.text_content("#run-id") == "c00001"
    assert "θi" in page.text_content("#pose")
    page.wait_for_function("!document.querySelector('#pause').disabled")
    shot = tmp_path / "web.png"
    page.screenshot(path=str(shot), full_page=True)
    keep = os.environ.get("GONIO_WEB_SCREENSHOT")
    if keep:
        shutil.copy(shot, keep)
    rgb = np.asarray(Image.open(shot).convert("RGB"))
    assert rgb.std() > 10.0                                   # not blank
    assert _colours(rgb) > 50                                 # text, bars, sketch, points
    page.click("#pause")
    wait_state(r.client, "c00001", "paused")
    page.wait_for_function("document.querySelector('#message').textContent.startsWith('pausing')")
    page.click("#resume")
    wait_state(r.client, "c00001", ("running", "finishing", "done"))
    page.fill("#token", "")                  # the operator at the rig, without the token: HALT still works
    page.click("#halt")
    st = wait_state(r.client, "c00001", ("halted", "done"))
    if st["state"] == "halted":
        page.wait_for_function("document.querySelector('#message').textContent.startsWith('halt')")
    r.client.post("/campaigns/c00001/abort")


def _colours(rgb: np.ndarray) -> int:
    """The distinct colours of an RGB image (uint8, H x W x 3): each colour marked in a table of all 2^24
    (np.unique(axis=0) sorted the full-page screenshot's millions of rows: 1.5-3 s of CPU)."""
    code = (rgb[..., 0].astype(np.int32) << 16) | (rgb[..., 1].astype(np.int32) << 8) | rgb[..., 2]
    seen = np.zeros(1 << 24, bool)
    seen[code.ravel()] = True
    return int(np.count_nonzero(seen))


def test_the_web_view_says_what_it_shows_in_sr_and_nothing_overlaps(serve, page, tmp_path):
    """The card read 'Running: c00001 done' with an ETA, the slice had no zero, no legend and f_r in
    units of ρ_ref/π, the arms' labels lay on top of each other at 0°, and there was no favicon."""
    r = serve()
    submit(r.client, grid="iso:step=30", material="lambert:albedo=0.5")
    wait_state(r.client, "c00001", "done")
    bad = []
    page.on("response", lambda resp: resp.status >= 400 and bad.append((resp.status, resp.url)))
    # every state the card shows, from the page's start: the event stream replays the finished campaign's
    # history (its 'running' first) after the card has read 'done' from the list
    page.add_init_script("""window.runStates = [];
        document.addEventListener('DOMContentLoaded', () => {
          const el = document.getElementById('run-state');
          new MutationObserver(() => window.runStates.push(el.textContent))
            .observe(el, {childList: true, characterData: true, subtree: true});
        });""")
    page.goto(r.url + "/")
    page.wait_for_function("document.querySelector('#run-state').textContent === 'done'")
    page.wait_for_function("document.querySelector('#conn').textContent === 'finished: done'")  # replayed
    states = page.evaluate("window.runStates")
    assert "done" in states and set(states[states.index("done"):]) == {"done"}, states
    # every in-plane reading replayed (the label counts them), and the reference's reflectance known
    page.wait_for_function("document.querySelector('#slice').dataset.fmax > 0 && "
                           "document.querySelector('#slice-label').textContent.includes('f_r in sr⁻¹)')")
    title = " ".join(page.text_content("#running-panel h2").split())
    assert title == "Campaign c00001 done" and "Running" not in title
    assert "ETA" not in page.text_content("#run-progress")
    assert page.get_attribute("#bar-fill", "style").replace(" ", "") in ("width:100%;", "width:100.0%;")
    # a Lambertian of albedo 0.5 is 0.5/π sr⁻¹ in every direction (it read 0.505 in units of ρ_ref/π)
    fmax = float(page.get_attribute("#slice", "data-fmax"))
    assert abs(fmax / (0.5 / np.pi) - 1) < 0.03, fmax
    assert int(page.get_attribute("#slice", "data-incidences")) >= 2
    # parked at home: both arms point up, and their labels must not overlap
    import json

    page.wait_for_function("document.querySelector('#sketch').dataset.labels")
    a, b = json.loads(page.get_attribute("#sketch", "data-labels"))
    assert "θi 0.0°" in page.text_content("#pose") and "θo 0.0°" in page.text_content("#pose")
    assert a["x"] + a["w"] <= b["x"] or b["x"] + b["w"] <= a["x"] or a["y"] + a["h"] <= b["y"] \
        or b["y"] + b["h"] <= a["y"], (a, b)
    assert page.get_attribute("link[rel=icon]", "href").startswith("data:image/svg+xml")
    assert bad == [], bad
    shot = tmp_path / "done.png"
    page.screenshot(path=str(shot), full_page=True)
    keep = os.environ.get("GONIO_WEB_SCREENSHOT")
    if keep:
        shutil.copy(shot, Path(keep).with_name("done-" + Path(keep).name))
