"""The live web view in a real headless browser (Debian's chromium, driven by Playwright): the queue,
the running campaign's progress, the pose sketch and a BRDF slice filling in; pause and resume buttons
with a token, and HALT without one. Skipped where chromium is not installed (tools/setup.sh installs it)."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from daemon_helpers import TOKEN, WAIT_S, submit, wait_state

CHROMIUM = "/usr/bin/chromium"
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-component-update", "--no-first-run"]

pytestmark = pytest.mark.skipif(not Path(CHROMIUM).exists(), reason="chromium is not installed "
                                "(apt-get install -y chromium; tools/setup.sh does it)")


@pytest.fixture
def page():
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS, headless=True)
        try:
            pg = browser.new_page(viewport={"width": 1200, "height": 800})
            pg.set_default_timeout(WAIT_S * 1000)
            yield pg
        finally:
            browser.close()


def test_the_web_view_follows_a_campaign_and_its_buttons_work(serve, page, tmp_path):
    from PIL import Image

    r = serve(token=TOKEN, pace=0.01)
    submit(r.client, grid="iso:step=10", material="ggx:alpha=0.2,metal=gold")
    page.goto(r.url + "/")
    page.wait_for_selector("#queue tbody tr[data-id='c00001']")
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
    img = np.asarray(Image.open(shot).convert("RGB"), float)
    assert img.std() > 10.0                                   # not blank
    assert len(np.unique(img.reshape(-1, 3), axis=0)) > 50    # text, bars, sketch, points
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
