"""The report's figures, drawn with matplotlib and returned as PNG bytes (embedded in the HTML)."""

from __future__ import annotations

import io

import numpy as np

from gonio.figure_layout import lay_out
from gonio.report.models import FRESNEL_THETA_D_DEG, PEAK_THETA_H_DEG

__all__ = ["png", "overview", "calibration", "albedo", "reciprocity", "residual_maps", "DPI"]

DPI = 100
_CHANNEL_COLOURS = {"R": "#d62728", "G": "#2ca02c", "B": "#1f77b4"}
_FLAG = "#c00000"
#: Residual maps: the colour scale ends here (%), so that a misfit of a few % still shows.
_CLIP_PERCENT = 25.0


def _figure(w, h):
    from matplotlib.figure import Figure

    return Figure(figsize=(w, h), dpi=DPI)


def png(fig) -> bytes:
    """A figure as PNG bytes, laid out first (:func:`lay_out`)."""
    lay_out(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    return buf.getvalue()


def _colour(ch: str, k: int) -> str:
    return _CHANNEL_COLOURS.get(ch, f"C{k}")


#: Per-channel curves drawn at most: a spectrometer's 41 bands are shown as this many, evenly spaced.
MAX_CURVES = 5


def shown_channels(channels) -> list[int]:
    """Indices of the channels drawn per channel: all of R, G, B; for a spectrometer's bands, at most
    :data:`MAX_CURVES` evenly spaced ones (first and last included).

    >>> shown_channels(("R", "G", "B"))
    [0, 1, 2]
    >>> shown_channels([f"{w}nm" for w in range(380, 790, 10)])
    [0, 10, 20, 30, 40]
    """
    n = len(channels)
    if n <= MAX_CURVES:
        return list(range(n))
    return sorted({int(round(x)) for x in np.linspace(0, n - 1, MAX_CURVES)})


def _marker(n: int, k: int) -> float:
    """Marker size: larger first for a few channels, so that coinciding ones (a grey standard) all show."""
    return 3.5 + 2.5 * (n - 1 - k) if n <= 3 else 4.0


def _time_axis(seconds: np.ndarray) -> tuple[np.ndarray, str]:
    top = float(np.max(seconds)) if len(seconds) else 0.0
    if top >= 3 * 3600:
        return seconds / 3600.0, "campaign time (h)"
    if top >= 180:
        return seconds / 60.0, "campaign time (min)"
    return seconds, "campaign time (s)"


def overview(b, data) -> bytes:
    """In-plane f_r (luminance) against signed θo for up to six measured θi: the data at a glance.

    Points are the measured samples of the plane of incidence, lines the campaign's interpolant
    (:func:`gonio.slices.polar_slice`) between neighbouring ones only (:func:`gonio.slices.polar_runs`: no
    line across what was not measured); ``gonio plot --kind polar`` draws the full figure.
    """
    from gonio.report.checks import sample_angles
    from gonio.slices import grid_step, luminance, polar_runs, polar_slice

    ang = sample_angles(data)
    top = min(b.theta_max_deg, 89.0)
    thetas = np.unique(np.round(ang[:, 0], 1))
    thetas = thetas[thetas <= top + 1e-9]
    if len(thetas) > 6:
        thetas = thetas[np.unique(np.round(np.linspace(0, len(thetas) - 1, 6)).astype(int))]
    s = polar_slice(b, thetas, 0.0)
    y = luminance(s.image, b.channels)
    signed = -90.0 + 180.0 * (np.arange(y.shape[1]) + 0.5) / y.shape[1]
    fig = _figure(10.0, 4.4)
    ax = fig.add_subplot()
    import matplotlib

    colours = matplotlib.colormaps["viridis"](np.linspace(0.0, 0.9, len(thetas)))
    values = luminance(np.asarray(data.value, np.float64), b.channels)
    dphi = np.mod(ang[:, 3] - ang[:, 1], 360.0)
    step = grid_step(b)
    in_plane = (np.abs(dphi - 180.0) < 0.05) | (dphi < 0.05) | (dphi > 359.95)
    # each sample, and where the campaign declares reciprocity its reciprocal (the same Δφ up to sign)
    members = [(ang[:, 0], ang[:, 2])] + ([(ang[:, 2], ang[:, 0])] if b.symmetries["reciprocity"] else [])
    for k, t in enumerate(thetas):
        x, v = [], []
        for ti, to in members:
            pick = (np.abs(ti - t) < 0.05) & (in_plane | (to < 0.05))
            x.append(np.where(np.abs(dphi[pick] - 180.0) < 0.05, to[pick], -to[pick]))
            v.append(values[pick])
        x, v = np.concatenate(x), np.concatenate(v)
        if t < 0.05:  # light at the pole: its samples lie in every plane, on both sides
            x, v = np.concatenate([x, -x]), np.concatenate([v, v])
        ax.plot(x, v, "o", ms=3.5, color=colours[k], label=f"θi = {t:g}°")
        for lx, ly in polar_runs(b, t, 0.0, signed, y[k], np.stack([x, x], axis=1), step):
            ax.plot(lx, ly, color=colours[k], lw=1.6)
    pos = y[np.isfinite(y) & (y > 0)]
    if pos.size and pos.max() / max(np.percentile(pos, 1), 1e-300) > 30:
        ax.set_yscale("log")
    ax.set_xlim(-90, 90)
    ax.set_xticks(range(-90, 91, 15))
    ax.set_xlabel("signed θo (°):  ← light side (φo = φi)  |  specular side (φo = φi + 180°) →")
    ax.set_ylabel("luminance Y of f_r (sr⁻¹)" if b.channels == ("R", "G", "B") else "f_r (sr⁻¹)")
    ax.grid(alpha=0.3, which="major")
    lines = "between\nneighbouring samples" if step else "where\nsomething was measured"
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False,
              title=f"points: measured\nlines: interpolant {lines}", title_fontsize=8)
    ax.set_title("f_r in the plane of incidence (φi = 0°)", fontsize=10)
    return png(fig)


def calibration(ref, dark, channels) -> bytes:
    """White-reference net rate (as % of its median) and dark rate against campaign time."""
    fig = _figure(10.0, 6.4)
    ax, dx = fig.subplots(2, 1, sharex=True)
    t, label = _time_axis(ref.time_s)
    shown = shown_channels(channels)
    n = len(shown)
    for j, k in enumerate(shown):
        ch = channels[k]
        pct = 100.0 * (ref.rate[:, k] / ref.scale[k] - 1.0)
        err = 100.0 * ref.stderr[:, k] / ref.scale[k]
        ax.errorbar(t, pct, yerr=err, fmt="o-", ms=_marker(n, j), lw=1.0, capsize=2,
                    color=_colour(ch, j), label=ch, alpha=0.85)
    if ref.flagged:
        worst = np.array([100.0 * (ref.rate[i] / ref.scale - 1.0) for i in ref.flagged])
        ax.plot(t[ref.flagged], worst.min(axis=1), "o", ms=14, mfc="none", mec=_FLAG, mew=2,
                label="flagged reading")
        for i in ref.flagged:
            ax.annotate(f"step {ref.step[i]}", (t[i], 100.0 * float(np.min(ref.rate[i] / ref.scale - 1.0))),
                        textcoords="offset points", xytext=(8, -14), color=_FLAG, fontsize=9)
    ax.axhline(0.0, color="0.5", lw=0.8)
    ax.set_ylabel("white reference, net of dark:\n% from its median")
    ax.set_title("White-reference readings over the campaign (the calibration interpolates between them "
                 "in time)", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    td = _scale_like(dark.time_s, ref.time_s)
    for j, k in enumerate(shown):
        ch = channels[k]
        dx.errorbar(td, dark.rate[:, k], yerr=dark.stderr[:, k], fmt="s-", ms=_marker(n, j), lw=1.0,
                    capsize=2, color=_colour(ch, j), label=ch, alpha=0.85)
    if dark.flagged:
        dx.plot(td[dark.flagged], dark.rate[dark.flagged].max(axis=1), "o", ms=14, mfc="none", mec=_FLAG,
                mew=2, label="flagged reading")
    dx.set_ylabel("dark signal\n(signal units per s)")
    dx.set_xlabel(label)
    dx.set_title("Dark readings over the campaign", fontsize=10)
    dx.grid(alpha=0.3)
    dx.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    return png(fig)


def _scale_like(seconds: np.ndarray, reference_seconds: np.ndarray) -> np.ndarray:
    """``seconds`` in the unit :func:`_time_axis` picks for ``reference_seconds``."""
    _, label = _time_axis(reference_seconds)
    return seconds / {"campaign time (h)": 3600.0, "campaign time (min)": 60.0}.get(label, 1.0)


def albedo(alb: dict) -> bytes:
    """Directional albedo against θi per channel, the 1.0 line, values above it marked."""
    fig = _figure(8.5, 4.2)
    ax = fig.add_subplot()
    th = alb["theta_i"]
    for j, k in enumerate(shown_channels(alb["channels"])):
        ch = alb["channels"][k]
        ax.plot(th, alb["albedo"][:, k], "o-", ms=3.5, color=_colour(ch, j), label=ch)
    over = alb["albedo"] > 1.0
    if over.any():
        rows, cols = np.nonzero(over)
        ax.plot(th[rows], alb["albedo"][rows, cols], "o", ms=11, mfc="none", mec=_FLAG, mew=2,
                label="above 1: violates\nenergy conservation")
    ax.axhline(1.0, color="k", ls="--", lw=1.0, label="1.0: the energy\nconservation limit")
    cov = alb["coverage"]
    if cov.min() < 0.999:
        ax.plot(th, cov, color="0.45", ls=":", lw=1.5, label="measured fraction of\nthe hemisphere "
                "(albedo is\na lower bound below 1)")
    ax.set_ylim(0.0, max(1.1, float(np.nanmax(alb["albedo"])) * 1.1))
    ax.set_xlim(0.0, 90.0)
    ax.set_xticks(range(0, 91, 15))
    ax.set_xlabel("θi, incidence angle (°)")
    ax.set_ylabel("directional albedo\n∫ f_r cos θo dωo")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    return png(fig)


def reciprocity(pairs: dict) -> bytes:
    """z-scores of the measured reciprocal pairs (histogram) and their relative differences by angle."""
    fig = _figure(10.0, 3.8)
    hx, sx = fig.subplots(1, 2)
    z = pairs["z"][np.isfinite(pairs["z"])]
    hx.hist(np.clip(z, -8, 8), bins=np.linspace(-8, 8, 33), color="0.45")
    for v in (-3, 3):
        hx.axvline(v, color=_FLAG, ls="--", lw=0.9)
    hx.set_xlabel("z = (f(ωi,ωo) − f(ωo,ωi)) / σ  (clipped to ±8; dashed: ±3)")
    hx.set_ylabel("pairs")
    hx.set_title(f"{pairs['pairs']} pairs; {100 * pairs['beyond_3']:.1f} % beyond ±3σ", fontsize=10)
    big = pairs["theta"].max(axis=1)
    sx.plot(big, 100.0 * pairs["relative"], "o", ms=3.5, color="0.3", alpha=0.7)
    sx.axhline(0.0, color="0.5", lw=0.8)
    sx.set_xlabel("larger of θi, θo (°)")
    sx.set_ylabel("(f(ωi,ωo) − f(ωo,ωi)) / mean  (%)")
    sx.set_title("relative difference of each pair (luminance)", fontsize=10)
    sx.grid(alpha=0.3)
    return png(fig)


def residual_maps(fits: list[dict]) -> bytes:
    """One panel per fitted model: (model − data)/data of every sample over (θh, θd), one colour scale."""
    from matplotlib.colors import Normalize

    ok = [r for r in fits if r["relative"] is not None]
    n = max(len(ok), 1)
    cols = min(n, 3)
    rows = (n + cols - 1) // cols
    fig = _figure(3.7 * cols + 1.0, 3.3 * rows + 0.3)
    # the colour bar is a narrow last column of the grid, beside every row
    grid = fig.add_gridspec(rows, cols + 1, width_ratios=[1.0] * cols + [0.075])
    axes = np.array([fig.add_subplot(grid[i, j]) for i in range(rows) for j in range(cols)])
    bar = fig.add_subplot(grid[:, cols])
    norm = Normalize(-_CLIP_PERCENT, _CLIP_PERCENT)
    sc = None
    for ax, r in zip(axes, ok, strict=False):
        rel = np.clip(100.0 * r["relative"], -_CLIP_PERCENT, _CLIP_PERCENT)
        sc = ax.scatter(r["theta_h"], r["theta_d"], c=rel, cmap="RdBu_r",
                        norm=norm, s=16, edgecolors="0.3", linewidths=0.3)
        ax.axvline(PEAK_THETA_H_DEG, color="0.2", lw=0.8, ls=":")
        ax.axhline(FRESNEL_THETA_D_DEG, color="0.2", lw=0.8, ls=":")
        ax.set_xlim(-2, 91)  # room for the markers of samples on the axes (mirror direction, θd = 0)
        ax.set_ylim(-2, 91)
        ax.set_xticks(range(0, 91, 30))
        ax.set_yticks(range(0, 91, 30))
        ax.set_title(f"#{r['rank']} {r['model']}\nχ²/dof {r['per_dof']:.3g}", fontsize=9.5)
        ax.set_xlabel("θh (°)", fontsize=9)
        ax.set_ylabel("θd (°)", fontsize=9)
    for ax in axes[len(ok):]:
        ax.set_visible(False)
    if sc is not None:
        fig.colorbar(sc, cax=bar, label=f"(model − data) / data  (%, clipped to ±{_CLIP_PERCENT:g})")
    else:
        bar.set_visible(False)
    return png(fig)


def phases(steps, adaptive: dict) -> np.ndarray:
    """Which phase of an adaptive campaign measured each sample (0: the pilot, k: round k), from the
    samples' journal ``steps`` and the rounds' first steps."""
    firsts = np.array([r["first_step"] for r in adaptive["rounds"]], dtype=np.int64)
    return np.searchsorted(firsts, np.asarray(steps, np.int64), side="right")


def half_angles_deg(data) -> tuple[np.ndarray, np.ndarray]:
    """(θh, θd) in degrees of each sample's planned directions (measured ones in a version 1 file)."""
    from gonio.geometry import sph_to_vec, to_half_diff

    angles = data.planned if data.planned is not None else np.stack(
        [data.theta_i, data.phi_i, data.theta_o, data.phi_o], axis=1)
    a = np.radians(np.asarray(angles, np.float64))
    th, _, td, _ = to_half_diff(sph_to_vec(a[:, 0], a[:, 1]), sph_to_vec(a[:, 2], a[:, 3]))
    return np.degrees(th), np.degrees(td)


def adaptive_poses(data, adaptive: dict) -> bytes:
    """Where an adaptive campaign's poses went: poses per phase (pilot, rounds), and every pose in
    half/difference angles (θh, θd), coloured by phase: the rounds crowd where the BRDF varies most."""
    phase = phases(data.step, adaptive)
    th, td = half_angles_deg(data)
    k = len(adaptive["rounds"])
    import matplotlib

    colours = matplotlib.colormaps["viridis"](np.linspace(0.0, 0.9, max(k, 1)))
    fig = _figure(10.0, 4.0)
    ax1, ax2 = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1, 1.6]})
    counts = np.bincount(phase, minlength=k + 1)
    ax1.bar(np.arange(k + 1), counts, color=["0.55", *colours[:k]])
    ax1.set_xticks(np.arange(k + 1), ["pilot", *[str(i) for i in range(1, k + 1)]], fontsize=7)
    ax1.set_xlabel("phase (pilot, then rounds)")
    ax1.set_ylabel("poses measured")
    ax1.set_title("poses per phase", fontsize=10)
    ax2.scatter(th[phase > 0], td[phase > 0], s=6, c=colours[np.clip(phase[phase > 0] - 1, 0, None)],
                label="rounds (colour: round)")
    ax2.scatter(th[phase == 0], td[phase == 0], s=22, marker="s", facecolors="none", edgecolors="0.3",
                label="pilot")
    ax2.set_xlabel("θh (°): half vector from the normal (0: specular)")
    ax2.set_ylabel("θd (°)")
    ax2.set_xlim(0, 90)
    ax2.set_ylim(0, 90)
    ax2.grid(alpha=0.3)
    ax2.legend(fontsize=8, loc="upper right")
    ax2.set_title("where the poses went", fontsize=10)
    return png(fig)

