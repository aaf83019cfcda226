"""The report as one self-contained HTML page: inline CSS, figures as base64 PNG, no external assets."""

from __future__ import annotations

import base64
from html import escape

import numpy as np

from gonio.report import checks, journal, models
from gonio.report.figures import shown_channels

__all__ = ["render", "SECTIONS", "LEVELS"]

#: Section ids, in page order (the tests look for each).
SECTIONS = ("summary", "campaign", "calibration", "reciprocity", "albedo", "invalid", "noise", "fits",
            "selection", "definitions")
#: Verdict levels and their labels (the label, not only the colour, carries the meaning).
LEVELS = {"ok": "OK", "flag": "FLAG", "note": "NOTE", "info": "INFO"}
_REGION_TITLES = {"peak": "specular peak", "fresnel": "Fresnel rise", "grazing": "grazing", "body": "body"}

_CSS = """
body { font-family: "DejaVu Sans", "Liberation Sans", Arial, sans-serif; color: #1a1a1a; background: #fff;
       margin: 0; line-height: 1.45; font-size: 15px; }
main { max-width: 1100px; margin: 0 auto; padding: 18px 28px 40px; }
h1 { font-size: 24px; margin: 8px 0 2px; }
h2 { font-size: 19px; margin: 30px 0 8px; padding-bottom: 4px; border-bottom: 2px solid #d0d7de; }
h3 { font-size: 16px; margin: 20px 0 6px; }
.sub { color: #555; margin: 0 0 12px; }
ul.verdicts { list-style: none; padding: 0; margin: 8px 0; }
ul.verdicts li { padding: 5px 8px; margin: 3px 0; border-left: 5px solid #999; background: #f6f8fa; }
ul.verdicts li.ok { border-color: #1a7f37; }
ul.verdicts li.flag { border-color: #c00000; background: #fff0f0; }
ul.verdicts li.note { border-color: #b58500; background: #fffbea; }
ul.verdicts li.info { border-color: #8c959f; }
.badge { display: inline-block; min-width: 44px; text-align: center; font-weight: bold; font-size: 12px;
         padding: 1px 5px; margin-right: 8px; border-radius: 3px; color: #fff; background: #8c959f; }
.badge.ok { background: #1a7f37; } .badge.flag { background: #c00000; } .badge.note { background: #9a6700; }
.topic { font-weight: bold; margin-right: 4px; }
table { border-collapse: collapse; margin: 6px 0 12px; font-size: 14px; }
th, td { border: 1px solid #d0d7de; padding: 3px 8px; text-align: left; vertical-align: top; }
th { background: #f0f3f6; }
td.num { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
td.fail { background: #ffe3e3; font-weight: bold; }
img { max-width: 100%; height: auto; display: block; margin: 8px 0 4px; border: 1px solid #eee; }
.caption { color: #555; font-size: 13px; margin: 0 0 14px; }
.cards { display: grid; grid-template-columns: repeat(auto-fill, minmax(320px, 1fr)); gap: 12px; }
.card { border: 1px solid #d0d7de; border-radius: 4px; padding: 6px 10px; }
.card h3 { margin-top: 4px; }
code { background: #f0f3f6; padding: 0 3px; border-radius: 3px; overflow-wrap: anywhere; }
"""


def _hms(seconds: float) -> str:
    s = int(round(seconds))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


def _img(data: bytes, alt: str, caption: str = "") -> str:
    src = base64.b64encode(data).decode("ascii")
    cap = f'<p class="caption">{escape(caption)}</p>' if caption else ""
    return f'<img alt="{escape(alt)}" src="data:image/png;base64,{src}">{cap}'


def _table(head: list[str] | None, rows: list[list], num: set | None = None, fail=None) -> str:
    """A table (no header row for ``head=None``); ``num`` = right-aligned columns, ``fail(r, c)`` → True
    marks a cell as failing."""
    num = num or set()
    out = ["<table>" + ("<tr>" + "".join(f"<th>{escape(h)}</th>" for h in head) + "</tr>" if head else "")]
    for r, row in enumerate(rows):
        cells = []
        for c, v in enumerate(row):
            cls = " ".join(x for x in ("num" if c in num else "", "fail" if fail and fail(r, c) else "") if x)
            cells.append(f"<td{f' class={chr(34)}{cls}{chr(34)}' if cls else ''}>{escape(str(v))}</td>")
        out.append("<tr>" + "".join(cells) + "</tr>")
    return "".join(out) + "</table>"


def _pm(value: float, sd: float) -> str:
    return f"{value:.4g} ± {sd:.2g}"


def _angles(a) -> str:
    return "θi {:g}°, φi {:g}°, θo {:g}°, φo {:g}°".format(*(round(x, 2) for x in a))


def _section_campaign(rep) -> str:
    f = rep.facts
    used = [k for k, v in f["symmetries"].items() if v] or ["none"]
    counts = " → ".join(f"{k} {v:,}" for k, v in f["counts"].items())
    infeasible = ", ".join(f"{k} {v}" for k, v in f["infeasible"].items()) or "none"
    est = f["estimated_s"]
    ratio = f" ({100 * (f['campaign_s'] / est - 1):+.1f} % against the estimate)" if est > 0 else ""
    rows = [
        ["measured", f"{f['what']} ({f['source']})"],
        ["gantry", f"{f['gantry']} ({f['design']} design)"],
        ["grid", f["grid"]],
        ["shortcuts used", ", ".join(used)],
        ["poses through the planner", counts],
        ["infeasible poses", infeasible],
        ["steps", f"{f['steps']['total']:,}: {f['steps']['pose']:,} poses, {f['steps']['dark']} darks, "
                  f"{f['steps']['reference']} white references; {f['measured']:,} measured"],
        ["duration (campaign time)", f"{_hms(f['campaign_s'])}; plan estimate {_hms(est)}"
                                     + ("" if f["lower_bound_s"] is None else
                                        f", lower bound {_hms(f['lower_bound_s'])}") + ratio],
        ["runs", f"{f['runs']} ({f['runs'] - 1} resume{'s' if f['runs'] != 2 else ''})"],
        ["faults, retries", f"{f['faults']} faults; {f['retries']} retried measurements"],
        ["created", f"{f['created']}, gonio {f['software_version']}, seed {f['seed']}"],
    ]
    html = _table(None, rows)
    if f["events"]:
        html += "<h3>Faults, retries, pauses and halts (journal events)</h3>" + _table(
            ["event", "campaign time", "step", "message"],
            [[e["kind"], _hms(e["campaign_s"] or 0.0), "" if e["step"] is None else e["step"], e["message"]]
             for e in f["events"]])
    else:
        html += "<p>The journal records no faults, retries, pauses or halts.</p>"
    return html


def _section_adaptive(rep) -> str:
    """An adaptive campaign: the pilot, the rounds and where their poses went."""
    from gonio.adaptive.plan import pilot_text

    a = rep.facts["adaptive"]
    rounds = a["rounds"]
    budget = (f"{a['budget_poses']:,} poses" if a["budget_poses"] is not None
              else f"{a['budget_s']:,.0f} s of estimated gantry time")
    spent = a["pilot_s"] + sum(r["estimated_s"] for r in rounds)
    rows = [
        ["budget", budget],
        ["pilot", f"{a['pilot_poses']:,} poses ({pilot_text(a)} from 0 to theta_max), "
                  f"estimated {_hms(a['pilot_s'])}"],
        ["rounds", f"{len(rounds)}: " + ", ".join(f"{r['poses']:,}" for r in rounds) + " poses"
                   if rounds else "none (the pilot spent the budget)"],
        ["estimated gantry time, all phases", _hms(spent)],
        *([["ended short of the budget", a["ended"]["reason"]]] if a.get("ended") else []),
        ["poses near the specular direction (θh ≤ 10°)",
         f"{100 * rep.adaptive['pilot']:.0f} % of the pilot's, {100 * rep.adaptive['rounds']:.0f} % of the "
         "rounds'"],
    ]
    return _table(None, rows) + _img(
        rep.figures["adaptive"], "poses per phase and their half/difference angles",
        "Each round was planned from the journal's readings once the steps before it were measured: one "
        "new pose in each cell whose leave-one-out residual, weighted by its share of the error, was "
        "largest (with a motion cost: per second of gantry time to reach it).")


def _channel_words(channels, values, fmt) -> str:
    """Each channel's value (``fmt`` of it), or for a spectrometer's many bands the range across them."""
    if len(channels) <= 4:
        return ", ".join(f"{c} {fmt(v)}" for c, v in zip(channels, values, strict=True))
    lo, hi = int(np.argmin(values)), int(np.argmax(values))
    return f"from {fmt(values[lo])} ({channels[lo]}) to {fmt(values[hi])} ({channels[hi]}) across the " \
           f"{len(channels)} bands"


def _drift_words(channels, drift) -> str:
    """Each channel's drift, or for a spectrometer's many bands the range across them."""
    words = _channel_words(channels, drift, lambda d: f"{100 * d:+.2f} %")
    return words if len(channels) <= 4 else f"{words} (figures: {len(shown_channels(channels))} of them)"


def _reference_words(facts) -> str:
    """What the calibration divided by: the white standard's albedo, or where the config gave it per
    channel (a reflectance per channel, a spectrum, an angular response) those values."""
    rho = facts.get("reference_reflectance")
    if rho is None:
        return ("Reference albedo (hemispherical reflectance of the white standard): "
                f"<b>{facts['reference_albedo']:g}</b>.")
    rho = np.asarray(rho, dtype=np.float64)
    said = f"{rho[0]:g} in every channel" if np.all(rho == rho[0]) else \
        _channel_words(facts["channels"], rho, lambda r: f"{r:g}")
    return ("Reference reflectance per channel (the white standard's reflectance times its angular response "
            f"where it is read, what the calibration divides by): <b>{said}</b>.")


def _section_calibration(rep) -> str:
    ref, dark, ch = rep.reference, rep.dark, rep.facts["channels"]
    html = (f"<p>{_reference_words(rep.facts)} {len(ref.step)} white-reference and "
            f"{len(dark.step)} dark readings. Drift of the white reference from the first to the last good "
            "reading: " + _drift_words(ch, ref.drift) + ".</p>")
    html += _img(rep.figures["calibration"], "white-reference and dark readings over campaign time",
                 "Top: each white-reference reading net of the dark, as % from the median, ±1 standard "
                 "error. Bottom: the dark readings. A circled reading is off its neighbours' interpolation "
                 f"by more than {100 * journal.REFERENCE_JUMP_RELATIVE:g} % (dark: "
                 f"{100 * journal.DARK_JUMP_RELATIVE:g} % of the reference level) and more than "
                 f"{journal.JUMP_Z:g} standard errors.")
    rows = []
    for name, r in (("white reference", ref), ("dark", dark)):
        for i in r.flagged:
            worst = int(np.argmax(np.abs(r.deviation[i])))
            rows.append([name, r.step[i], _hms(r.time_s[i]),
                         f"{100 * r.deviation[i][worst]:+.1f} % ({ch[worst]})"])
    if rows:
        html += "<h3>Flagged readings</h3>" + _table(
            ["reading", "step", "campaign time", "off its neighbours' interpolation"], rows, num={1, 3})
    return html


def _section_reciprocity(rep) -> str:
    p = rep.pairs
    if not p["applicable"]:
        return ("<p>No reciprocal pairs: this campaign used the reciprocity shortcut, so each pair was "
                "measured once and the other member is taken from it. Measure with "
                "<code>reciprocity=false</code> in the GRID to check reciprocity.</p>")
    if not p["pairs"]:
        return "<p>The campaign measured without the shortcut, but no pair has both members measured.</p>"
    w = p["worst"]
    html = (f"<p>{p['pairs']} pairs with both members measured. rms z {p['rms_z']:.2f}; "
            f"{100 * p['beyond_3']:.1f} % beyond ±3σ (0.3 % expected for honest Gaussian errors); median "
            f"|relative difference| {100 * p['median_relative']:.2f} %; largest {100 * w[4]:+.1f} % at "
            f"{_angles(w[:4])}.</p>")
    return html + _img(rep.figures["reciprocity"], "reciprocity residuals of the measured pairs",
                       "Left: z-scores of f(ωi,ωo) − f(ωo,ωi) in units of their combined stddev. Right: "
                       "relative difference of each pair against the larger of its two polar angles.")


def _section_albedo(rep) -> str:
    a = rep.albedo
    over = ", ".join(f"{t:g}°" for t in a["over"])
    text = (f"<p>Largest directional albedo {a['max']:.3f} at θi = {a['at']:g}° (φi = {a['phi_i_deg']:g}°). "
            + (f"<b>Above 1 at θi = {over}</b>: more energy out than in." if a["flag"] else
               "Not above 1 anywhere: energy is conserved.")
            + (f" The measured part of the hemisphere covers {100 * a['coverage'].min():.0f}–"
               f"{100 * a['coverage'].max():.0f} % of its projected solid angle, so the values are lower "
               "bounds." if a["coverage"].min() < 0.999 else "") + "</p>")
    return text + _img(rep.figures["albedo"], "directional albedo against incidence angle",
                       f"Integrated over the measured directions every {checks.ALBEDO_STEP_DEG:g}° of θi.")


def _section_invalid(rep) -> str:
    v = rep.invalid
    if not v["flag"]:
        return f"<p>None of the {v['samples']:,} samples is negative or NaN.</p>"
    html = (f"<p><b>{v['negative']} samples negative</b> ({v['negative_values']} values) and <b>{v['nan']} "
            f"samples NaN</b> ({v['nan_values']} values) of {v['samples']:,}. A negative f_r is a dark "
            "subtraction larger than the signal; a NaN a reading that failed.</p>")
    rows = [[r["step"], _angles(r["angles"]), ", ".join(r["channels"]),
             ", ".join(f"{x:.3g}" for x in r["values"])] for r in v["rows"][:25]]
    more = f"<p>… and {len(v['rows']) - 25} more.</p>" if len(v["rows"]) > 25 else ""
    return html + _table(["step", "direction (planned)", "channels", "f_r (sr⁻¹)"], rows, num={0}) + more


def _section_noise(rep) -> str:
    html = ("<p>What is measured: repeated readings of the same thing, compared with the standard error each "
            "reading states. z = deviation / stated stddev; its rms is ≈ 1 when the stated stddev is honest, "
            f"above {checks.NOISE_UNDERSTATED:g} it is understated (uncertainties too optimistic), below "
            f"{checks.NOISE_OVERSTATED:g} overstated; judged from {checks.NOISE_MIN_READINGS} readings or "
            "more.</p>")
    rows = [[r["what"], r["n"], "–" if not np.isfinite(r["rms_z"]) else f"{r['rms_z']:.2f}", r["verdict"]]
            for r in rep.noise["rows"]]
    html += _table(["repeat readings", "readings", "rms z", "verdict"], rows, num={1, 2},
                   fail=lambda r, c: c == 3 and "understated" in rows[r][3])
    best = next((m for m in rep.fits if m["result"] is not None), None)
    if best is not None:
        html += (f"<p>For comparison, the best-fitting model ({escape(best['model'])}) leaves χ²/dof = "
                 f"{best['per_dof']:.3g}: near 1 the samples scatter about a smooth model as their stddev "
                 "says (when the model is right).</p>")
    return html


def _section_fits(rep) -> str:
    rows = []
    for m in rep.fits:
        if m["result"] is None:
            rows.append(["–", m["model"], "–", "–", "–", "–", m["error"]])
            continue
        res = m["result"].residual
        rows.append([m["rank"], m["model"], f"{m['per_dof']:.4g}", res["dof"],
                     f"{100 * res['rms_relative']:.3g} %",
                     f"{res['structure']:.2f}" if np.isfinite(res["structure"]) else "– (too few samples)",
                     "structured misfit" if res["misfit"] else ""])
    fitted = next((m["result"] for m in rep.fits if m["result"] is not None), None)
    optics = ""
    if fitted is not None and fitted.aperture is not None:
        optics = (" Each model is averaged over the cones the readings integrate, as the instrument "
                  f"measures it: {escape(fitted.aperture.describe())}.")
    elif fitted is not None:
        optics = (" Each model is evaluated at the measured directions: the source and detector cones the "
                  "readings integrate are not recorded, so their smoothing of a sharp lobe is not modelled.")
    html = ("<p>Each model fitted to every measured sample (χ² with the measured stddev, "
            f"<code>gonio fit</code>), ranked by its error per degree of freedom.{optics}</p>")
    html += _table(["rank", "model", "χ²/dof", "dof", "rms / data", "structure", "fit flag"], rows,
                   num={0, 2, 3, 4, 5})
    html += '<div class="cards">'
    for m in rep.fits:
        if m["result"] is None:
            continue
        r = m["result"]
        prow = [[k, _pm(v["value"], v["stddev"]) + (" (at bound)" if v["at_bound"] else "")]
                for k, v in r.parameters.items()]
        html += (f'<div class="card"><h3>#{m["rank"]} {escape(m["model"])}</h3>'
                 + _table(["parameter", "value ± 1σ"], prow, num={1})
                 + f"<p>χ²/dof {m['per_dof']:.4g} over {r.residual['dof']} degrees of freedom.<br>"
                 f"<code>{escape(r.material)}</code></p></div>")
    html += "</div>"
    caption = ("Residual of each sample, (model − data)/data, over the half angle θh and difference angle "
               f"θd; dotted lines: θh = {models.PEAK_THETA_H_DEG:g}° and θd = "
               f"{models.FRESNEL_THETA_D_DEG:g}°, the bounds of the peak and Fresnel regions (grazing is "
               "a matter of θi and θo, not of this plane). Red: model too high; blue: too low.")
    return html + _img(rep.figures["residuals"], "residual maps of the fitted models over half and "
                       "difference angle", caption)


def _section_selection(rep) -> str:
    ok = [m for m in rep.fits if m["result"] is not None]
    names = list(models.REGIONS)
    counts = {k: (ok[0]["regions"][k]["n"] if ok else 0) for k in names}
    head = ["rank", "model"] + [f"{_REGION_TITLES[k]} (n={counts[k]})" for k in names]
    rows, flags = [], []
    for m in ok:
        cells = []
        for k in names:
            g = m["regions"][k]
            cells.append("–" if not g["n"] else f"{100 * g['bias']:+.1f} % / {100 * g['rms']:.1f} %"
                         + (" FAILS" if g["flag"] else ""))
        rows.append([m["rank"], m["model"], *cells])
        flags.append([False, False] + [m["regions"][k]["flag"] for k in names])
    html = ("<p>The models from best to worst, with their residual in each angular region as bias / rms "
            "relative to the data (bias > 0: the model is too high). A cell marked FAILS is off by more than "
            f"{100 * models.REGION_RELATIVE:g} % rms and by more than {models.REGION_CHI2:g}× the noise "
            "(mean z²).</p>")
    html += _table(head, rows, num=set(range(2, 2 + len(names))), fail=lambda r, c: flags[r][c])
    lines = "".join(f"<li><b>{escape(m['model'])}</b> (χ²/dof {m['per_dof']:.3g}): {escape(m['words'])}</li>"
                    for m in ok)
    return html + f"<ul>{lines}</ul>"


def _section_definitions() -> str:
    items = [
        f"Specular peak: θh < {models.PEAK_THETA_H_DEG:g}° and θd < {models.FRESNEL_THETA_D_DEG:g}°; Fresnel "
        f"rise: θd ≥ {models.FRESNEL_THETA_D_DEG:g}°; grazing: max(θi, θo) ≥ {models.GRAZING_THETA_DEG:g}° "
        "(not in the first two); body: the rest. θh, θd: Rusinkiewicz half and difference angles.",
        f"A region fails when rms(model − data)/rms(data) > {100 * models.REGION_RELATIVE:g} % and mean z² > "
        f"{models.REGION_CHI2:g}, with at least {models.REGION_MIN_SAMPLES} samples.",
        f"White reference: a reading off its neighbours' interpolation in time by > "
        f"{100 * journal.REFERENCE_JUMP_RELATIVE:g} % and > {journal.JUMP_Z:g} σ; dark: by > "
        f"{100 * journal.DARK_JUMP_RELATIVE:g} % of the net reference rate and > {journal.JUMP_Z:g} σ.",
        f"Reciprocity: flagged when > {100 * checks.RECIPROCITY_BEYOND_3:g} % of the pairs lie beyond ±3σ "
        f"and the median |relative difference| is > {100 * checks.RECIPROCITY_RELATIVE:g} %.",
        "Energy: directional albedo above 1 in any channel at any θi.",
        f"Noise: rms z of {checks.NOISE_MIN_READINGS} or more repeat readings > "
        f"{checks.NOISE_UNDERSTATED:g} (understated stddev).",
    ]
    return "<ul>" + "".join(f"<li>{escape(t)}</li>" for t in items) + "</ul>"


def render(rep) -> str:
    """The page for a :class:`gonio.report.Report`."""
    f = rep.facts
    verdicts = "".join(
        f'<li class="{lvl}"><span class="badge {lvl}">{LEVELS[lvl]}</span>'
        f'<span class="topic">{escape(topic)}:</span>{escape(text)}</li>'
        for lvl, topic, text in rep.verdicts)
    parts = [
        ("summary", "Summary", f'<ul class="verdicts">{verdicts}</ul>'),
        ("campaign", "The campaign", _section_campaign(rep)),
        *([("adaptive", "Adaptive acquisition: where the poses went", _section_adaptive(rep))]
          if f.get("adaptive") else []),
        ("calibration", "Calibration: white reference and dark", _section_calibration(rep)),
        ("overview", "The data at a glance", _img(rep.figures["overview"], "in-plane BRDF for several θi",
                                                  "gonio plot --kind polar|hemisphere|merl draws more.")),
        ("reciprocity", "Check: reciprocity", _section_reciprocity(rep)),
        ("albedo", "Check: energy conservation (directional albedo)", _section_albedo(rep)),
        ("invalid", "Check: negative and NaN values", _section_invalid(rep)),
        ("noise", "Check: noise against the stated stddev", _section_noise(rep)),
        ("fits", "Model fits side by side", _section_fits(rep)),
        ("selection", "Model selection: where each model fails", _section_selection(rep)),
        ("definitions", "How this report decides", _section_definitions()),
    ]
    body = "".join(f'<section id="{sid}"><h2>{escape(title)}</h2>{html}</section>'
                   for sid, title, html in parts)
    title = f"gonio campaign report: {f['name']}"
    return (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"><title>{escape(title)}</title>'
            f"<style>{_CSS}</style></head><body><main><h1>{escape(title)}</h1>"
            f'<p class="sub">{escape(f["what"])} · {escape(f["grid"])} · {escape(f["gantry"])}</p>'
            f"{body}</main></body></html>\n")
