"""gonio report: every section of a simulated campaign, flags for a bad white reference and for negative or
NaN values, model selection (a wrong model flagged at the peak, the right one not), the CLI's refusals,
and the page as a real headless browser renders it."""

import base64
import io
import re
import shutil
import sqlite3
import subprocess
from pathlib import Path

import numpy as np
import planned
import pytest
from built_once import built_once

from gonio.campaign import create_campaign, finish_campaign, open_campaign
from gonio.cli import main
from gonio.config import load_config, parse_config
from gonio.lifecycle import run_campaign
from gonio.plan.schedule import STEP_POSE, STEP_REFERENCE
from gonio.report import build_report, report
from gonio.report.checks import NOISE_UNDERSTATED
from gonio.report.html import SECTIONS
from gonio.report.models import DEFAULT_MODELS
from gonio.store import Journal
from gonio.wiring import build_gantry

COPPER = "ggx:alpha=0.15,metal=copper,rho_d=0.2,rho_s=0.8"
GRID = "iso:step=15,theta_max=75"
CHROMIUM = Path("/usr/bin/chromium")


def _run(folder, material, grid, cfg=None, seed=1, before=None):
    cfg = cfg or load_config()
    c = planned.create(folder, cfg, grid=grid, material=material, seed=seed)
    try:
        g = build_gantry(c.cfg, material, seed=seed)
        if before is not None:
            before(g)
        run_campaign(c, g)
    finally:
        c.close()
    return folder


def _often_referenced(every: int = 8, **reference):
    """The sim gantry with a dark and a white reference every ``every`` poses (as well as every 300 s):
    enough of each on a small grid for the report's scatter checks; ``reference``: more of the white
    standard's settings."""
    data = load_config().model_dump()
    data["reference"].update(every=every, **reference)
    return parse_config(data)


def _tamper(folder, change):
    """Rewrite some readings in the journal (``change(conn)``), then calibrate and write brdf.h5 again."""
    conn = sqlite3.connect(folder / "campaign.sqlite")
    with conn:
        change(conn)
    conn.close()
    c = open_campaign(folder)
    try:
        finish_campaign(c)
    finally:
        c.close()


def _set_signal(conn, step, signal):
    conn.execute("UPDATE measurements SET signal = ? WHERE step = ?",
                 (np.ascontiguousarray(signal, dtype="<f8").tobytes(), int(step)))


def _verdict(rep, topic):
    return next(v for v in rep.verdicts if v[1] == topic)


@pytest.fixture(scope="module")
def copper(tmp_path_factory):
    """Measured without the reciprocity shortcut, with one transient axis time-out (one retry); in raster
    order (the tour takes 0.4 s longer to plan, and no check here depends on the order). Built once per run
    (tests/built_once.py): the tests only read it."""
    def build(parent):
        folder, out = parent / "copper", parent / "copper.html"
        _run(folder, COPPER, GRID + ",reciprocity=false,order=raster", _often_referenced(50), seed=2,
             before=lambda g: g.axes["detector_tilt"].fail_next("timeout"))
        return folder, out, report(folder, out)

    return built_once(tmp_path_factory, "report-copper", build)


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """lambert:albedo=0.8 on iso:step=30 with references every 8 poses, the white standard given per
    channel: the one to tamper with (each test tampers with a copy); built once per run."""
    return built_once(tmp_path_factory, "report-lambert", lambda parent: _run(
        parent / "lambert", "lambert:albedo=0.8", "iso:step=30",
        _often_referenced(reflectance=[0.99, 0.97, 0.95])))


# -- a good campaign -----------------------------------------------------------------------------------
def test_the_report_has_every_section_and_says_what_the_campaign_was(copper):
    folder, out, rep = copper
    page = out.read_text(encoding="utf-8")
    for sid in SECTIONS:
        assert f'<section id="{sid}">' in page, sid
    assert page.index('id="summary"') < page.index('id="campaign"')  # verdicts first
    facts = rep.facts
    assert facts["grid"].startswith("iso:step=15,theta_max=75,reciprocity=false")
    assert facts["retries"] == 1 and facts["faults"] == 0
    assert [e["kind"] for e in facts["events"]] == ["retry"]
    assert "retry" in page and "no faults, retries" not in page
    assert facts["steps"]["pose"] == facts["poses"] and facts["measured"] == facts["steps"]["total"]
    assert abs(facts["campaign_s"] / facts["estimated_s"] - 1) < 0.1
    assert _verdict(rep, "campaign")[0] == "note"  # a retry is worth a look, not a flag
    assert "1 retries" in _verdict(rep, "campaign")[2]
    assert facts["reference_reflectance"] is None  # the standard's albedo alone calibrated it
    albedo = facts["reference_albedo"]
    assert f"Reference albedo (hemispherical reflectance of the white standard): <b>{albedo:g}</b>" in page
    # nothing is wrong with this campaign's data
    assert rep.flags == {"reference": False, "dark": False, "reciprocity": False, "albedo": False,
                         "invalid": False, "noise": False}
    assert "None of the" in page and "negative or NaN" in page
    # every reading of the white reference and every reciprocal pair were looked at
    assert len(rep.reference.step) == facts["steps"]["reference"]
    assert rep.pairs["applicable"] and rep.pairs["pairs"] > 100
    assert f"{rep.pairs['pairs']} pairs with both members measured" in page
    noise = {r["what"].split(" ")[0]: r for r in rep.noise["rows"]}
    assert 0.5 < noise["white-reference"]["rms_z"] < 2.0 and noise["reciprocal"]["n"] == rep.pairs["pairs"]


def test_models_are_ranked_and_a_missing_fresnel_term_is_found_where_it_shows(copper):
    _, out, rep = copper
    ranked = [m["model"] for m in rep.fits]
    assert ranked[0] == "ggx" and sorted(ranked) == sorted(DEFAULT_MODELS)
    per_dof = [m["per_dof"] for m in rep.fits]
    assert per_dof == sorted(per_dof) and [m["rank"] for m in rep.fits] == [1, 2, 3, 4]
    best = rep.fits[0]
    # copper's conductor Fresnel rises at large θd; ggx fits it without Fresnel: only there it fails
    assert best["flagged"] == ["fresnel"]
    assert "in the Fresnel rise" in best["words"]
    for m in rep.fits[1:]:  # no lobe, or no diffuse part: fails at the peak too
        assert "peak" in m["flagged"], m["model"]
    page = out.read_text(encoding="utf-8")
    for m in rep.fits:
        for name, p in m["result"].parameters.items():
            assert name in page and f"{p['value']:.4g} ± {p['stddev']:.2g}" in page


def test_the_default_models_recover_a_ggx_with_a_diffuse_part(copper, capsys):
    """The defaults were single-lobe models beside lambert+ggx: on this ggx + diffuse copper, the ggx lobe
    alone found alpha = 0.67 (made with 0.15) and ward's ended at its bounds. Each default model is now
    its material, the diffuse part included; ggx finds the material it was made from."""
    _, _, rep = copper
    assert DEFAULT_MODELS == ("lambert", "ward", "cook-torrance", "ggx")
    with pytest.raises(SystemExit):
        main(["report", "--help"])
    assert f"(default: {', '.join(DEFAULT_MODELS)}:" in " ".join(capsys.readouterr().out.split())
    fits = {m["model"]: m["result"].parameters for m in rep.fits}
    ggx = fits["ggx"]
    assert abs(ggx["alpha"]["value"] / 0.15 - 1) < 0.03, ggx["alpha"]
    for ch in "RGB":
        assert abs(ggx[f"rho_d.{ch}"]["value"] / 0.2 - 1) < 0.03, ggx
    assert not any(p["at_bound"] for p in ggx.values())
    for model in ("ward", "cook-torrance"):   # their lobes' widths are found, not bounds
        width = fits[model]["alpha" if "ward" in model else "m"]
        assert not width["at_bound"] and 0.1 < width["value"] < 0.3, (model, width)


# -- model selection -------------------------------------------------------------------------------------
def test_cook_torrance_fitted_with_phong_is_flagged_at_the_peak_and_the_right_model_is_not(tmp_path):
    folder = _run(tmp_path / "ct", "cook-torrance:d=beckmann,m=0.3,metal=gold", GRID + ",order=raster")
    rep = build_report(folder, "phong,cook-torrance:metal=gold")
    right, wrong = rep.fits
    assert (right["model"], wrong["model"]) == ("cook-torrance:metal=gold", "phong")
    assert right["rank"] == 1 and wrong["rank"] == 2
    assert "peak" in wrong["flagged"] and wrong["regions"]["peak"]["bias"] < -0.2  # the lobe is too low there
    assert wrong["words"].startswith("fails") and "at the specular peak (too low by" in wrong["words"]
    assert right["flagged"] == [] and right["words"].startswith("fits in every region")
    assert _verdict(rep, "phong")[2].startswith("fails ")  # a summary line for the model that fails
    assert _verdict(rep, "best model")[2].startswith("cook-torrance:metal=gold (χ²/dof")
    assert re.search(r"phong</td><td class=\"num fail\">[^<]*FAILS", rep.html)


def test_a_ggx_campaign_fitted_with_ggx_is_not_flagged_anywhere(tmp_path):
    folder = _run(tmp_path / "ggx", "ggx:alpha=0.25,fresnel=none,rho_s=0.8", GRID + ",order=raster")
    rep = build_report(folder, ["ggx"])
    (m,) = rep.fits
    assert m["flagged"] == [] and all(r["n"] >= 3 for r in m["regions"].values())
    assert all(r["rms"] < 0.02 for r in m["regions"].values())
    assert _verdict(rep, "best model")[0] == "ok"
    assert "FAILS</td>" not in rep.html
    # the reciprocity shortcut was used: the report says there are no pairs rather than passing them
    assert not rep.pairs["applicable"] and _verdict(rep, "reciprocity")[0] == "info"
    assert "used the reciprocity shortcut" in rep.html


# -- flags ---------------------------------------------------------------------------------------------------
def test_a_bad_white_reference_reading_is_flagged_by_its_step(small, tmp_path):
    folder = tmp_path / "bad-ref"
    shutil.copytree(small, folder)
    j = Journal.open(folder / "campaign.sqlite", readonly=True)
    refs = [m for m in j.measurements() if m.kind == STEP_REFERENCE]
    j.close()
    assert len(refs) >= 4
    bad = refs[len(refs) // 2]
    _tamper(folder, lambda conn: _set_signal(conn, bad.step, 0.6 * np.asarray(bad.signal)))
    rep = build_report(folder, "lambert")
    assert rep.flags["reference"] and not rep.flags["dark"]
    assert [int(rep.reference.step[i]) for i in rep.reference.flagged] == [bad.step]
    level, _, text = _verdict(rep, "white reference")
    assert level == "flag" and f"step {bad.step} (-40 %)" in text
    assert "Flagged readings" in rep.html
    assert f'<td>white reference</td><td class="num">{bad.step}</td>' in rep.html


def test_a_white_reference_that_reads_low_throughout_shows_as_albedo_above_1(small, tmp_path):
    """A soiled standard: every reading 0.4x, consistent over time, so only energy conservation catches it
    (the samples come out 2.5x too bright: an albedo of 0.8 reads 2)."""
    folder = tmp_path / "soiled"
    shutil.copytree(small, folder)
    j = Journal.open(folder / "campaign.sqlite", readonly=True)
    refs = [m for m in j.measurements() if m.kind == STEP_REFERENCE]
    j.close()

    def change(conn):
        for m in refs:
            _set_signal(conn, m.step, 0.4 * np.asarray(m.signal))

    _tamper(folder, change)
    rep = build_report(folder, "lambert")
    assert not rep.flags["reference"] and rep.flags["albedo"]
    a = rep.albedo
    assert a["max"] > 1.2 and 30.0 in a["over"]
    level, _, text = _verdict(rep, "energy")
    assert level == "flag" and text.startswith("directional albedo above 1 at θi = ") and "30°" in text
    assert "more energy out than in" in rep.html


def test_negative_and_nan_values_are_counted_and_located(small, tmp_path):
    folder = tmp_path / "bad-values"
    shutil.copytree(small, folder)
    j = Journal.open(folder / "campaign.sqlite", readonly=True)
    poses = [m for m in j.measurements() if m.kind == STEP_POSE]
    j.close()
    negative, nan = poses[3:6], poses[10]

    def change(conn):
        for m in negative:
            _set_signal(conn, m.step, -np.abs(m.signal) - 1.0)
        _set_signal(conn, nan.step, [np.nan, 1.0, 1.0])

    _tamper(folder, change)
    rep = build_report(folder, "lambert")
    v = rep.invalid
    assert (v["negative"], v["negative_values"], v["nan"], v["nan_values"]) == (3, 9, 1, 1)
    assert sorted(r["step"] for r in v["rows"]) == sorted([m.step for m in negative] + [nan.step])
    row = next(r for r in v["rows"] if r["step"] == nan.step)
    assert row["channels"] == ["R"] and row["angles"] == pytest.approx(list(nan.angles_deg), abs=0.05)
    assert _verdict(rep, "values") == ("flag", "values", f"3 negative and 1 NaN samples of {v['samples']}")
    assert "3 samples negative</b> (9 values)" in rep.html


# -- the CLI -------------------------------------------------------------------------------------------------
def test_cli_writes_the_report_and_prints_its_verdicts(small, tmp_path, capsys):
    out = tmp_path / "r.html"
    assert main(["report", str(small), "--out", str(out), "--models", "lambert,lambert+ggx"]) == 0
    printed = capsys.readouterr().out
    assert str(out) in printed and "OK" in printed and "lambert" in printed
    page = out.read_text(encoding="utf-8")
    assert page.startswith("<!DOCTYPE html>") and "lambert+ggx" in page
    # what the calibration divided by: the standard per channel, not the config's albedo it left unused
    assert "what the calibration divides by): <b>R 0.99, G 0.97, B 0.95</b>." in page
    assert "Reference albedo" not in page
    assert list(tmp_path.iterdir()) == [out]  # no temporary file left beside it


@pytest.mark.parametrize("case, says", [
    ("unfinished", "the campaign is incomplete (0/9 steps measured)"),
    ("nothing", "no such campaign folder"),
    ("model", "--models: model 'blinn': unknown model 'blinn'; allowed: lambert"),
    ("folder", "--out: folder {tmp}/no/such does not exist"),
    ("suffix", "--out: {tmp}/r.pdf must end in .html"),
    ("dir", "--out: {tmp} is a folder"),
])
def test_cli_bad_input_is_one_line_exit_2_and_writes_nothing(small, tmp_path, capsys, case, says):
    target, out, models = small, tmp_path / "r.html", []
    if case == "unfinished":
        target = tmp_path / "c"
        create_campaign(target, load_config(), grid="iso:step=45", material="lambert:albedo=0.5").close()
    elif case == "nothing":
        target = tmp_path / "nothing"
    elif case == "model":
        models = ["--models", "lambert,blinn"]
    elif case == "folder":
        out = tmp_path / "no" / "such" / "r.html"
    elif case == "suffix":
        out = tmp_path / "r.pdf"
    elif case == "dir":
        out = tmp_path
    before = sorted(tmp_path.rglob("*"))
    assert main(["report", str(target), "--out", str(out), *models]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and says.replace("{tmp}", str(tmp_path)) in err, err
    # nothing written (reading a journal may leave SQLite's -wal/-shm files beside it, as any reader does)
    assert [p for p in sorted(tmp_path.rglob("*")) if p not in before and ".sqlite-" not in p.name] == []


# -- the page in a browser ---------------------------------------------------------------------------------
def _png(data: bytes) -> np.ndarray:
    from matplotlib.image import imread

    return imread(io.BytesIO(data), format="png")[..., :3]


def _not_blank(img: np.ndarray) -> None:
    assert img.shape[0] > 200 and img.shape[1] > 300
    assert img.var() > 0.005  # not one colour
    assert np.mean(img.sum(axis=2) < 2.8) > 0.02  # a real share of the pixels is drawn, not background


def test_every_embedded_plot_decodes_and_is_not_blank_and_nothing_is_loaded_from_outside(copper):
    _, out, rep = copper
    page = out.read_text(encoding="utf-8")
    images = re.findall(r'<img alt="([^"]+)" src="data:image/png;base64,([^"]+)"', page)
    assert len(images) == len(rep.figures) == 5
    for _, data in images:
        _not_blank(_png(base64.b64decode(data)))
    assert not re.search(r'(src|href)="(?!data:)', page)  # no external asset
    assert "url(" not in page and "@import" not in page


@pytest.mark.skipif(not CHROMIUM.exists(), reason="needs Debian's chromium (/usr/bin/chromium)")
def test_the_page_renders_in_a_headless_browser(copper, tmp_path):
    _, out, _ = copper
    shot = tmp_path / "shot.png"
    subprocess.run([str(CHROMIUM), "--headless", "--no-sandbox", "--disable-gpu",
                    "--disable-background-networking", "--disable-component-update", "--no-first-run",
                    f"--user-data-dir={tmp_path / 'profile'}",
                    f"--screenshot={shot}", "--window-size=1200,3000", out.resolve().as_uri()],
                   check=True, capture_output=True, timeout=120)
    img = _png(shot.read_bytes())
    assert img.shape[:2] == (3000, 1200)
    _not_blank(img)
    # the verdict badges at the top are drawn: green (OK) pixels in the first screenful
    top = img[:700]
    green = (top[..., 1] > 0.4) & (top[..., 0] < 0.2) & (top[..., 2] < 0.3)
    assert green.sum() > 200


def test_a_lamp_drifting_smoothly_between_sparse_references_is_not_flagged(tmp_path):
    """References far apart in time on a lamp that warms up and wanders: the calibration's cubic follows
    the drift, so the report does not call those readings jumps or their noise understated, although
    the straight line through each one's two neighbours misses them by several standard errors."""
    data = load_config().model_dump()
    data["light"]["sim"].update(drift_per_hour=-0.2, warmup_fraction=0.03, warmup_s=180.0,
                                wander_fraction=0.05, wander_period_s=540.0)
    data["reference"].update(every=None, every_s=30.0)
    data["detector"]["sim"].update(aperture_samples=4096)
    data["detector"]["sim"]["noise"].update(shot_counts_per_unit=1e9)
    folder = _run(tmp_path / "drift", "lambert:albedo=0.5", "iso:step=15", parse_config(data))
    rep = build_report(folder)
    r = rep.reference
    assert len(r.step) >= 8
    assert r.flagged == [] and not rep.flags["reference"] and not rep.flags["noise"]
    rows = {row["what"].split(" ")[0]: row for row in rep.noise["rows"]}
    assert 0.5 < rows["white-reference"]["rms_z"] < 2.0
    # The straight line through each one's two neighbours would not do: its scatter would call the
    # stated stddev understated.
    t, y, s = r.time_s, r.rate[:, 1], r.stderr[:, 1]
    line = y[:-2] + (y[2:] - y[:-2]) * ((t[1:-1] - t[:-2]) / (t[2:] - t[:-2]))
    z_line = (y[1:-1] - line) / np.hypot(s[1:-1], 0.7 * s[2:])
    assert np.sqrt(np.mean(z_line**2)) > NOISE_UNDERSTATED


def test_the_noise_check_judges_readings_not_channels_and_only_enough_of_them():
    """Three grey readings of three channels are three readings, not nine: too few to call their stated
    stddev too large from an rms z of 0.2; ten such readings are enough."""
    from gonio.report.checks import NOISE_MIN_READINGS, noise_check
    from gonio.report.journal import Readings

    def readings(k):
        z = np.full((k, 3), 0.2)
        one = np.ones((k, 3))
        return Readings(np.arange(k), np.arange(k, dtype=float), one, one, np.ones(3), z=z, deviation=z)

    none = {"applicable": False}
    few = noise_check(readings(3), readings(NOISE_MIN_READINGS), none)["rows"]
    assert few[0]["n"] == 3 and not few[0]["tested"] and few[0]["verdict"].startswith("too few readings")
    assert few[1]["tested"] and "overstated" in few[1]["verdict"]
