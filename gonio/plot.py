"""Pictures of a measured BRDF (``gonio plot``): PNG or PDF figures (matplotlib) and EXR float images.

``plot(source, kind, out)`` opens a campaign folder or ``brdf.h5`` through :mod:`gonio.brdf` and draws
one of the kinds of :data:`gonio.registries.PLOT_KINDS` (each a :class:`PlotKind`); an ``.exr`` ``out``
gets the float values of the same slice instead of a figure (pixel mapping in :mod:`gonio.slices`,
repeated in the EXR header). The built-in kinds:

- ``polar``: in-plane f_r for several θi on polar axes (normal up, specular side right), the measured
  samples of that plane as points with ±1σ error bars, and lines through the interpolant that join
  neighbouring samples only (one grid step apart on an ``iso`` or ``full`` grid): a line never crosses
  what was not measured (the blocked cone about ωo = ωi, where the light arm hides the detector; beyond
  θmax), which is hatched per θi along the bottom instead; log radius when the values span more than a
  decade and a half (glossy lobes), down to the least measured point.
- ``hemisphere``: f_r over ωo for one ωi (``theta_i_deg``, ``phi_i_deg``), seen from above; the blocked
  cone outlined.
- ``merl``: f_r over (θh, θd) at φd = 90°, the usual image slice of MERL-style data.
- ``reciprocity``: the relative difference f(ωi, ωo) vs f(ωo, ωi) over (θi, θo) in the plane of
  incidence, and the z-scores of every measured pair; only for campaigns measured without the
  reciprocity shortcut.
- ``albedo``: directional albedo against θi with the 1.0 line of energy conservation.

Figures show the luminance Y (Rec. 709 weights) of R, G, B data (the albedo plot shows each channel);
EXR files hold every channel.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gonio.brdf import MeasuredBRDF, open_brdf
from gonio.dataset import BRDF_NAME, SampledBRDF, read_brdf
from gonio.figure_layout import PAD_IN, inside, lay_out
from gonio.formats import atomic_path
from gonio.registries import PLOT_KINDS
from gonio.slices import (
    LUMA,
    Slice,
    albedo_slices,
    blocked_cone_deg,
    blocked_deg,
    grid_step,
    hemisphere_slice,
    luminance,
    merl_slice,
    polar_runs,
    polar_slice,
    reciprocity_slice,
    write_exr,
)

__all__ = ["plot", "PlotKind", "SUFFIXES", "PlotReport", "POLAR", "HEMISPHERE", "MERL", "RECIPROCITY",
           "ALBEDO"]

SUFFIXES = (".png", ".pdf", ".exr")
# Values spanning more than this ratio get a logarithmic axis.
_LOG_RATIO = 30.0
_NAN_COLOUR = "#d9d9d9"


@dataclass(frozen=True)
class PlotKind:
    """A kind of plot (the target of a :data:`gonio.registries.PLOT_KINDS` entry).

    Attributes
    ----------
    slice : callable
        ``slice(b, data, theta_i_deg, phi_i_deg) -> Slice``: the values the plot shows
        (:mod:`gonio.slices`), from the open BRDF ``b`` (:class:`~gonio.brdf.MeasuredBRDF`) and its samples
        ``data``; an ``.exr`` output holds exactly these.
    draw : callable
        ``draw(b, data, slice, title, report) -> matplotlib.figure.Figure``: the figure of a ``.png`` or
        ``.pdf`` output; it may add notes and what it shows to ``report`` (:class:`PlotReport`).
    """

    slice: Callable
    draw: Callable


@dataclass
class PlotReport:
    """What :func:`plot` wrote: the file, the slice behind it, and notes worth printing."""

    kind: str
    path: Path
    slice: Slice
    notes: list = field(default_factory=list)
    #: What a figure shows beyond the slice, by name (the albedo plot: ``hemisphere`` (T, C), the albedo
    #: over the whole hemisphere with its gaps filled, and ``peak_unmeasured`` (T,) bool; a log-polar
    #: plot: ``polar_rlim``, its radial range, and ``least``, the least value drawn; every polar plot:
    #: ``polar_lines``, per θi the (x, Y) runs drawn as unbroken lines, x the signed θo in degrees,
    #: ``polar_unmeasured``, per θi the (lo, hi) spans of signed θo hatched as not measured,
    #: ``polar_step``, the grid step that makes samples neighbours (None: off-lattice data), and
    #: ``polar_ylim``, the right panel's range of f_r).
    shown: dict = field(default_factory=dict)

    def __str__(self) -> str:
        return f"{self.kind}: {self.path}" + "".join(f"\n  {n}" for n in self.notes)


def plot(source, kind: str, out, *, theta_i_deg: float = 30.0, phi_i_deg: float = 0.0) -> PlotReport:
    """Draw a measured BRDF.

    Parameters
    ----------
    source : str, Path or SampledBRDF
        A campaign folder, its ``brdf.h5``, or data already read.
    kind : str
        A name of :data:`gonio.registries.PLOT_KINDS`.
    out : str or Path
        ``.png``, ``.pdf`` (a figure) or ``.exr`` (the slice's float values); its folder must exist.
    theta_i_deg, phi_i_deg : float
        Degrees: ωi of ``hemisphere``; φi (the plane of incidence) of ``polar``, ``reciprocity`` and
        ``albedo``.

    Returns
    -------
    PlotReport
    """
    if kind not in PLOT_KINDS:
        raise ValueError(f"plot kind {kind!r} is unknown; allowed: {', '.join(PLOT_KINDS.names())}")
    how: PlotKind = PLOT_KINDS.load(kind)
    out = Path(out)
    if out.suffix.lower() not in SUFFIXES:
        raise ValueError(f"output {str(out)!r}: the suffix picks the format; allowed: {', '.join(SUFFIXES)}")
    if not (np.isfinite(theta_i_deg) and 0.0 <= theta_i_deg < 90.0):
        raise ValueError(f"theta_i_deg: must be in [0, 90) degrees, got {theta_i_deg}")
    if not np.isfinite(phi_i_deg):
        raise ValueError(f"phi_i_deg: must be a finite number of degrees, got {phi_i_deg}")
    data, name = _read(source)
    b = open_brdf(data)
    s = how.slice(b, data, theta_i_deg, phi_i_deg)
    meta = {"campaign": name, "material": _what(b), "grid": str(b.attrs.get("grid", "")),
            "units": s.quantity, "cosine": "none",
            # NaN within this cone about ωi: the light arm hides the detector (gonio.slices)
            "blocked_cone_deg": blocked_cone_deg(b)}
    report = PlotReport(kind, out, s)
    if out.suffix.lower() == ".exr":
        write_exr(out, s, meta)
        return report
    fig = how.draw(b, data, s, _title(name, b), report)
    laid_out = fig.get_layout_engine() is None
    if laid_out:  # laid out in one pass, to the figure's edges (gonio.figure_layout)
        lay_out(fig)
    # cropped to what is drawn where a title wider than the figure, or constrained layout, needs it
    tight = {} if laid_out and inside(fig) else {"bbox_inches": "tight"}
    with atomic_path(out) as tmp:
        fig.savefig(tmp, format=out.suffix.lower()[1:], dpi=150, **tight)
    return report


def _read(source) -> tuple[SampledBRDF, str]:
    if isinstance(source, SampledBRDF):
        return source, str(source.attrs.get("material") or "dataset")
    path = Path(source)
    h5 = path / BRDF_NAME if path.is_dir() else path
    if not h5.is_file():
        raise ValueError(f"plot source {str(source)!r}: no such campaign folder or {BRDF_NAME} file")
    return read_brdf(h5), (path.name if path.is_dir() else h5.parent.name) or str(path)


def _what(b: MeasuredBRDF) -> str:
    return str(b.attrs.get("material") or b.attrs.get("sample") or "")


def _title(name: str, b: MeasuredBRDF, width: int = 80) -> str:
    """The campaign's name, then what was measured on which grid, wrapped only between ``key=value``
    items (a spec broken inside a number, ``rho_s=0.`` / ``8``, reads as another value)."""
    parts = (_what(b), str(b.attrs.get("grid", "")).split(",order=")[0])
    return "\n".join([f"campaign {name}", *(line for p in parts if p for line in wrap_items(p, width))])


def wrap_items(text: str, width: int) -> list[str]:
    """``text`` in lines of at most ``width`` characters where it can, broken only after a comma or
    before a `` · ``; an item longer than ``width`` stays whole.

    >>> wrap_items("ggx:alpha=0.15,metal=copper,rho_d=0.2,rho_s=0.8 · iso:step=15", 30)
    ['ggx:alpha=0.15,metal=copper,', 'rho_d=0.2,rho_s=0.8', '· iso:step=15']
    """
    import re

    lines: list[str] = []
    for part in filter(None, re.split(r"(?<=,)|(?= · )", text)):
        if lines and len(lines[-1]) + len(part.rstrip()) <= width:
            lines[-1] += part
        else:
            lines.append(part.strip())
    return [line.strip() for line in lines]


def _incidences(b: MeasuredBRDF, data: SampledBRDF, most: int = 6) -> np.ndarray:
    """θi values to draw: the planned ones (read-back angles scatter about them; at most ``most``, evenly
    chosen), else every 15°."""
    src = data.planned[:, 0] if data.planned is not None else np.asarray(data.theta_i)
    top = min(b.theta_max_deg, 89.0)
    values = np.unique(np.round(np.asarray(src, float), 1))
    values = values[values <= top + 1e-9]
    if not 2 <= len(values) <= 60:
        values = np.arange(0.0, top + 1e-9, 15.0)
    if len(values) > most:
        values = values[np.unique(np.round(np.linspace(0, len(values) - 1, most)).astype(int))]
    return values


@dataclass
class _AlbedoSlice(Slice):
    """The albedo of the measured part (what an ``.exr`` holds) and, for the figure, ``whole``: the image of
    the whole hemisphere's albedo (``albedo_slice(fill=True)``), from the same evaluations of f_r."""

    whole: np.ndarray | None = None


def _albedo_slice(b, data, theta_i_deg, phi_i_deg) -> Slice:
    top = min(b.theta_max_deg, 89.0)
    measured, whole = albedo_slices(b, np.linspace(0.0, top, max(2, int(round(top / 2.5)) + 1)), phi_i_deg)
    return _AlbedoSlice(**vars(measured), whole=whole.image)


def _figure(w=6.4, h=5.2, layout: str | None = "constrained"):
    """A figure; ``layout=None``: laid out by :func:`gonio.figure_layout.lay_out` when it is saved (the
    kinds without a colour bar beside an image of fixed aspect)."""
    from matplotlib.figure import Figure

    return Figure(figsize=(w, h), layout=layout)


def _norm(values: np.ndarray):
    """A log colour/axis norm when positive values span more than _LOG_RATIO, else linear."""
    from matplotlib.colors import LogNorm, Normalize

    pos = values[np.isfinite(values) & (values > 0)]
    if pos.size == 0:
        return Normalize(0.0, 1.0), False
    lo, hi = np.percentile(pos, 0.5), pos.max()
    if hi / max(lo, 1e-300) > _LOG_RATIO:
        return LogNorm(max(lo, hi * 1e-4), hi), True
    return Normalize(0.0, hi), False


def _cmap(name: str):
    import matplotlib

    return matplotlib.colormaps[name].with_extremes(bad=_NAN_COLOUR)


def _ylabel(b) -> str:
    return "luminance Y of f_r (sr⁻¹)" if b.channels == ("R", "G", "B") else f"f_r {b.channels[0]} (sr⁻¹)"


# -- polar --------------------------------------------------------------------------------------------
def _in_plane_samples(b, data, theta_i, phi_i, tol=0.5):
    """Measured samples in the plane of incidence at θi: (signed θo deg, Y, σY, planned signed θo deg).
    A sample belongs by its planned pose where the data have one (read-back angles scatter about it) and
    sits at the θo where :mod:`gonio.brdf` places it."""
    ang = data.planned if b.angles == "planned" else np.stack(
        [data.theta_i, data.phi_i, data.theta_o, data.phi_o], axis=1)
    ang = np.asarray(ang, float)
    plan = ang if data.planned is None else np.asarray(data.planned, float)
    y = luminance(data.value, b.channels)
    w2 = LUMA ** 2 if b.channels == ("R", "G", "B") else np.eye(1, len(b.channels))[0]
    sy = np.sqrt(np.asarray(data.stddev, float) ** 2 @ w2)
    members = [(plan[:, 0], plan[:, 1], plan[:, 2], plan[:, 3], ang[:, 2])]
    if b.symmetries["reciprocity"]:
        members.append((plan[:, 2], plan[:, 3], plan[:, 0], plan[:, 1], ang[:, 0]))
    out = []
    for ti, pi_, to, po, at in members:
        rel = np.mod(po - pi_, 360.0) if b.symmetries["isotropy"] else np.mod(po - phi_i, 360.0)
        same_plane = np.ones_like(ti, bool) if b.symmetries["isotropy"] else \
            (np.abs((pi_ - phi_i + 180.0) % 360.0 - 180.0) <= tol) | (ti <= tol)
        forward = np.abs(rel - 180.0) <= tol
        back = (rel <= tol) | (rel >= 360.0 - tol)
        pick = (np.abs(ti - theta_i) <= tol) & same_plane & (forward | back | (to <= tol))
        sign = np.where(forward, 1.0, -1.0)
        out.append(np.stack([sign * at, y, sy, sign * to], axis=1)[pick])
        # ωi at the pole has no azimuth: its samples lie in every plane, on both sides.
        pole = pick & (ti <= tol)
        out.append(np.stack([-sign * at, y, sy, -sign * to], axis=1)[pole])
    pts = np.concatenate(out)
    return np.unique(pts, axis=0) if len(pts) else pts


def _unmeasured_spans(runs, top):
    """The spans of [−top, top] (signed θo, degrees) that no run covers, wider than half a degree."""
    spans, at = [], -top
    for x, _ in sorted(runs, key=lambda r: r[0][0]):
        if x[0] - at > 0.5:
            spans.append((float(at), float(x[0])))
        at = max(at, float(x[-1]))
    if top - at > 0.5:
        spans.append((float(at), float(top)))
    return spans


def _draw_polar(b, data, s, title, report):
    import matplotlib
    from matplotlib.patches import Patch

    fig = _figure(11.5, 5.2, layout=None)
    ax = fig.add_subplot(1, 2, 1, projection="polar")
    cx = fig.add_subplot(1, 2, 2)
    ax.set_theta_zero_location("N")
    ax.set_theta_direction(-1)
    ax.set_thetamin(-90)
    ax.set_thetamax(90)
    rows = s.attrs["rows_deg"]
    phi_i = s.attrs["phi_i_deg"]
    signed = -90.0 + 180.0 * (np.arange(s.image.shape[1]) + 0.5) / s.image.shape[1]
    y = luminance(s.image, b.channels)
    step = grid_step(b)
    top = min(b.theta_max_deg, 90.0)
    points = [_in_plane_samples(b, data, t, phi_i) for t in rows]
    lines = [polar_runs(b, t, phi_i, signed, y[k], p[np.isfinite(p[:, 1])][:, [0, 3]], step)
             for k, (t, p) in enumerate(zip(rows, points, strict=True))]
    gaps = [_unmeasured_spans(runs, top) for runs in lines]
    report.shown.update(polar_lines=lines, polar_unmeasured=gaps, polar_step=step)
    allv = np.concatenate([np.zeros(0)] + [r[1] for runs in lines for r in runs] + [p[:, 1] for p in points])
    norm, log = _norm(allv)
    colours = matplotlib.colormaps["viridis"](np.linspace(0.0, 0.9, len(rows)))
    least = norm.vmin
    if log:  # every measured point stays on the axes, however far below the bulk of the values
        pos = allv[np.isfinite(allv) & (allv > 0)]
        least = min(least, float(pos.min()))
    strip = min(0.035, 0.25 / max(len(rows), 1))
    for k, t in enumerate(rows):
        p = points[k]
        for x, v in lines[k]:
            ax.plot(np.radians(x), v, color=colours[k], lw=1.6)
            cx.plot(x, v, color=colours[k], lw=1.6)
        if len(p):
            for axis, px in ((ax, np.radians(p[:, 0])), (cx, p[:, 0])):
                axis.errorbar(px, p[:, 1], yerr=p[:, 2], fmt="o", ms=3.2, color=colours[k], ecolor=colours[k],
                              elinewidth=1.0, capsize=1.5)
        cx.plot([], [], color=colours[k], lw=1.6, marker="o", ms=3.2, label=f"θi = {t:g}°")
        cx.axvline(t, color=colours[k], lw=0.7, ls=":")  # the mirror direction of this θi
        for lo, hi in gaps[k]:  # a strip per θi along the bottom: where that θi has no line
            cx.axvspan(lo, hi, ymin=k * strip, ymax=(k + 1) * strip, facecolor=(*colours[k][:3], 0.12),
                       edgecolor=colours[k], hatch="////", lw=0.0, zorder=0.5)
    for lo, hi in ((-90.0, -top), (top, 90.0)):
        if hi - lo > 0.1:
            cx.axvspan(lo, hi, color=_NAN_COLOUR, lw=0, zorder=0.4)
            ax.fill_between(np.radians(np.linspace(lo, hi, 30)), 0.0, 1.0, transform=ax.get_xaxis_transform(),
                            color=_NAN_COLOUR, lw=0, zorder=0.4)
    room = strip * len(rows) if any(gaps) else 0.0  # the strips' share of the height, below the data
    if log:
        ax.set_rscale("log")
        # The centre of a log-polar plot is a value, not zero: a decade below the least one drawn, so
        # that a diffuse body sits well out from the centre instead of crowding into it.
        ax.set_rlim(polar_floor(least), norm.vmax * 1.5)
        report.shown.update(polar_rlim=ax.get_ylim(), least=float(least))
        cx.set_yscale("log")
        lo, hi = np.log10(least * 0.7), np.log10(norm.vmax * 1.5)
        cx.set_ylim(10.0 ** ((lo - room * hi) / (1.0 - room)), 10.0 ** hi)
    else:
        ax.set_rlim(0.0, norm.vmax * 1.08)
        hi = norm.vmax * 1.08
        cx.set_ylim(-room * hi / (1.0 - room), hi)
        cx.set_yticks([t for t in cx.get_yticks() if 0.0 <= t <= hi])  # no negative f_r on the scale
    report.shown.update(polar_ylim=cx.get_ylim())
    ax.set_thetagrids(range(-90, 91, 30), [f"{abs(a)}°" for a in range(-90, 91, 30)])
    ax.set_rlabel_position(-90)
    ax.tick_params(axis="y", labelsize=7)
    ax.set_title(f"radius: {_ylabel(b)}{', log scale' if log else ''}\nangle: θo from the normal,  "
                 "← light side  |  specular side →", fontsize=8.5)
    cx.set_xlim(-90, 90)
    cx.set_xticks(range(-90, 91, 30))
    cx.set_xlabel("signed θo (°):  ← light side (φo = φi)  |  specular side (φo = φi + 180°) →")
    cx.set_ylabel(_ylabel(b) + (", log scale" if log else ""))
    cx.grid(alpha=0.3, which="major")
    handles, labels = cx.get_legend_handles_labels()
    handles += [Patch(facecolor="none", edgecolor="0.35", hatch="////", lw=0.0),
                Patch(facecolor=_NAN_COLOUR, lw=0)]
    labels += ["not measured at that θi\n(near ωo = ωi the light arm\nblocks the detector)",
               f"beyond θmax = {top:.3g}°:\nnot measured"]
    joined = "lines join neighbouring\nmeasured samples" if step is not None else \
        "lines: interpolant where\nsomething was measured"
    cx.legend(handles, labels, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False,
              title=f"{joined}\npoints: measured ±1σ\ndotted: mirror θo", title_fontsize=8)
    fig.text(0.5, 1.0 - PAD_IN / fig.get_figheight(), f"{title}\nin-plane f_r, plane of incidence "
             f"φi = {phi_i:g}°", fontsize=10, ha="center", va="top")  # over both panels
    return fig


#: The log-polar panel's centre, in decades below the least value drawn.
POLAR_DECADES_BELOW = 1.0


def polar_floor(least: float) -> float:
    """The radius at the centre of a log-polar panel whose least value drawn is ``least``."""
    return least * 10.0 ** -POLAR_DECADES_BELOW


# -- hemisphere -------------------------------------------------------------------------------------
def _draw_hemisphere(b, data, s, title, report):
    fig, ax, bar = _with_colour_bar(6.4, 5.4)
    y = luminance(s.image, b.channels)
    norm, log = _norm(y)
    im = ax.imshow(y, extent=(-90, 90, -90, 90), cmap=_cmap("inferno"), norm=norm, interpolation="nearest")
    fig.colorbar(im, cax=bar, label=_ylabel(b) + (" (log scale)" if log else ""))
    circle = np.linspace(0, 2 * np.pi, 361)
    for r in (30, 60, 90):
        ax.plot(r * np.cos(circle), r * np.sin(circle), color="0.55", lw=0.6)
        ax.text(r * np.cos(np.radians(-60)), r * np.sin(np.radians(-60)), f"θo={r}°", color="0.35",
                fontsize=7, ha="left", va="top")
    ti, pi_ = s.attrs["theta_i_deg"], np.radians(s.attrs["phi_i_deg"])
    ax.plot(ti * np.cos(pi_ + np.pi), ti * np.sin(pi_ + np.pi), "+", color="cyan", ms=12, mew=2,
            label="mirror direction")
    ax.plot(ti * np.cos(pi_), ti * np.sin(pi_), "x", color="cyan", ms=9, mew=2, label="light (ωi)")
    cone = blocked_cone_deg(b)
    if cone > 0.0:  # where the light arm hides the detector: NaN in the slice, outlined here
        x, y = _cone_outline(ti, s.attrs["phi_i_deg"], cone)
        ax.fill(x, y, facecolor="none", edgecolor="cyan", hatch="////", lw=0.8,
                label=f"not measured: the light arm\nblocks the detector (< {cone:g}° from ωi)")
    ax.legend(loc="lower left", fontsize=7, framealpha=0.8)
    ax.set_xlabel("θo cos φo (°)   (+x: sample reference direction)")
    ax.set_ylabel("θo sin φo (°)")
    ax.set_aspect("equal")
    ax.set_title(f"{title}\nf_r over ωo for θi = {ti:g}°, φi = {s.attrs['phi_i_deg']:g}° (seen from above); "
                 "grey: not measured", fontsize=10)
    return fig


def _cone_outline(theta_i_deg, phi_i_deg, cone_deg, n=121):
    """The edge of the cone of half-angle ``cone_deg`` about ωi, in the hemisphere plot's projection
    (θo cos φo, θo sin φo), degrees."""
    from gonio.geometry import sph_to_vec, vec_to_sph

    wi = sph_to_vec(np.radians(theta_i_deg), np.radians(phi_i_deg))
    u = np.cross(wi, [0.0, 0.0, 1.0] if abs(wi[2]) < 0.9 else [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(wi, u)
    a = np.linspace(0.0, 2.0 * np.pi, n)[:, None]
    c = np.radians(cone_deg)
    t, p = vec_to_sph(np.cos(c) * wi + np.sin(c) * (np.cos(a) * u + np.sin(a) * v))
    return np.degrees(t) * np.cos(p), np.degrees(t) * np.sin(p)


def _with_colour_bar(w, h):
    """A figure laid out by :func:`gonio.figure_layout.lay_out` with one square image and its colour bar
    (a narrow last column, an empty one between; the image keeps to its right edge, near the bar)."""
    fig = _figure(w, h, layout=None)
    grid = fig.add_gridspec(1, 3, width_ratios=[1.0, 0.03, 0.05])
    ax = fig.add_subplot(grid[0, 0])
    ax.set_anchor("E")
    return fig, ax, fig.add_subplot(grid[0, 2])


# -- merl -------------------------------------------------------------------------------------------
def _draw_merl(b, data, s, title, report):
    fig, ax, bar = _with_colour_bar(6.2, 5.2)
    y = luminance(s.image, b.channels)
    norm, log = _norm(y)
    im = ax.imshow(y, extent=(0, 90, 0, 90), cmap=_cmap("magma"), norm=norm, interpolation="nearest")
    fig.colorbar(im, cax=bar, label=_ylabel(b) + (" (log scale)" if log else ""))
    cone = blocked_cone_deg(b)
    if cone > 0.0:  # ωi·ωo = cos 2θd: the blocked cone is θd < cone / 2, NaN in the slice
        ax.axhspan(0.0, 0.5 * cone, facecolor="none", edgecolor="0.35", hatch="////", lw=0.0,
                   label=f"θd < {0.5 * cone:g}°: not measured,\nthe light arm blocks the detector")
        ax.legend(loc="upper right", fontsize=7, framealpha=0.8)
    ax.set_xlabel("θh, half-vector angle from the normal (°)")
    ax.set_ylabel("θd, difference angle (°)")
    ax.set_xticks(range(0, 91, 15))
    ax.set_yticks(range(0, 91, 15))
    ax.set_title(f"{title}\nf_r over (θh, θd) at φd = {s.attrs['phi_d_deg']:g}°; grey: not measured",
                 fontsize=10)
    return fig


# -- reciprocity ------------------------------------------------------------------------------------
def _draw_reciprocity(b, data, s, title, report):
    fig = _figure(10.5, 4.6)
    ax, hx = fig.subplots(1, 2, width_ratios=(1.25, 1.0))
    top = s.attrs["theta_max_deg"]
    rel = luminance(s.image, b.channels) if b.channels == ("R", "G", "B") else s.image[..., 0]
    finite = np.abs(rel[np.isfinite(rel)])
    lim = max(float(np.percentile(finite, 99.5)) if finite.size else 0.0, 1e-6)
    im = ax.imshow(100.0 * rel, extent=(0, top, 0, top), cmap=_cmap("RdBu_r"), vmin=-100 * lim,
                   vmax=100 * lim, interpolation="nearest")
    fig.colorbar(im, ax=ax, label="(f(ωi,ωo) − f(ωo,ωi)) / mean  (%)", shrink=0.9)
    ax.set_xlabel("θi (°)")
    ax.set_ylabel("θo (°)")
    median = 100 * np.median(finite) if finite.size else 0.0
    ax.set_title(f"in-plane, φo = φi + 180°; median |diff| {median:.2g} %\ngrey: not measured, or θi > θo "
                 "(the same with the opposite sign)", fontsize=9)
    from gonio.report.checks import reciprocity_pairs

    # Each pair measured both ways, once: the same pairs, z-scores and counts as the report's check.
    pairs = reciprocity_pairs(data, b)
    z = pairs["z"][np.isfinite(pairs["z"])]
    if z.size:
        hx.hist(np.clip(z, -6, 6), bins=np.linspace(-6, 6, 49), color="0.4")
        for at, colour in ((2, "C1"), (3, "C3")):
            hx.axvline(-at, color=colour, ls="--", lw=0.8)
            hx.axvline(at, color=colour, ls="--", lw=0.8, label=f"±{at}σ")
        hx.legend(fontsize=8)
        beyond2, beyond3 = (float(np.mean(np.abs(z) > a)) for a in (2.0, 3.0))
        hx.set_title(f"{z.size} measured pairs: {100 * beyond3:.1f} % beyond ±3σ, "
                     f"{100 * beyond2:.1f} % beyond ±2σ\n(0.27 % and 4.6 % where the pairs agree within "
                     "their stated σ)", fontsize=9)
        report.notes.append(f"{z.size} measured pairs, each counted once; {100 * beyond3:.1f} % differ from "
                            f"their reciprocal by more than 3 sigma, {100 * beyond2:.1f} % by more than "
                            "2 sigma")
    hx.set_xlabel("z = (f(ωi,ωo) − f(ωo,ωi)) / √(σ₁² + σ₂²)   (clipped to ±6)")
    hx.set_ylabel("pairs")
    fig.suptitle(f"{title}\nHelmholtz reciprocity residual (luminance Y)", fontsize=10)
    return fig


# -- albedo -----------------------------------------------------------------------------------------
def _draw_albedo(b, data, s, title, report):
    """Per channel: the whole hemisphere, each unmeasured cell taking the least f_r measured on its θo
    ring (solid; exact for a diffuse sample, no peak added that was not measured), and the measured part
    alone (dotted; a lower bound). Shaded: incidences whose
    specular direction lies where nothing was measured (the occlusion gap around retro-reflection
    holds the mirror direction at small θi), where the albedo misses the specular peak."""
    fig = _figure(6.8, 4.6, layout=None)
    ax = fig.add_subplot()
    th = np.asarray(s.attrs["cols_deg"])
    phi = float(s.attrs["phi_i_deg"])
    cov = np.asarray(s.attrs["coverage"])
    lower = s.image[0]
    whole = s.whole[0]
    from gonio.brdf import Reason

    mirror = (th, np.full_like(th, phi), th, np.full_like(th, phi + 180.0))
    # at small θi the mirror direction lies in the blocked cone about ωi, whatever an engine answers there
    peak_gap = (b.eval_deg(*mirror).reason == Reason.NO_DATA) | blocked_deg(b, *mirror)
    report.shown.update(hemisphere=whole, peak_unmeasured=peak_gap)
    colours = {"R": "#d62728", "G": "#2ca02c", "B": "#1f77b4"}
    n = len(b.channels)
    for k, ch in enumerate(b.channels):
        colour = colours.get(ch, f"C{k}")
        # widest first, so that channels that coincide (a grey sample) stay visible as nested lines
        ax.plot(th, whole[:, k], color=colour, lw=1.2 + 1.6 * (n - 1 - k), alpha=0.85, label=ch, zorder=2 + k)
        ax.plot(th, lower[:, k], color=colour, lw=1.0, ls=":", alpha=0.9, zorder=2 + k)
    ax.axhline(1.0, color="k", ls="--", lw=1.0, label="1.0: energy\nconservation limit")
    ax.plot([], [], color="0.3", lw=1.0, ls=":", label="measured part only\n(a lower bound)")
    top = max(1.08, float(np.nanmax(whole)) * 1.1)
    ax.set_ylim(0.0, top)
    ax.set_xlim(0.0, 90.0)
    ax.set_xticks(range(0, 91, 15))
    ax.set_xlabel("θi, incidence angle (°)")
    ax.set_ylabel("directional albedo ∫ f_r cos θo dωo")
    for lo, hi in _runs(th, peak_gap):
        ax.axvspan(lo, hi, color="#f2c14e", alpha=0.35, lw=0, zorder=1)
        ax.text(0.5 * (lo + hi), 0.04 * top, "specular\ndirection\nnot measured\n(occlusion\ngap)",
                ha="center", va="bottom", fontsize=7.5, color="0.25")
        report.notes.append(f"θi {lo:g}–{hi:g}°: the specular direction lies in the occlusion gap, where "
                            "nothing was measured; the albedo there misses any specular peak")
    lo_c, hi_c = f"{100 * cov.min():.1f}", f"{100 * cov.max():.1f}"
    span = lo_c if lo_c == hi_c else f"{lo_c}–{hi_c}"
    if cov.min() < 0.999:
        report.notes.append(f"solid: the whole hemisphere, the unmeasured {100 - 100 * cov.max():.1f}–"
                            f"{100 - 100 * cov.min():.1f} % taking the least f_r measured at the same θo; "
                            f"dotted: the measured part alone ({span} %), a lower bound")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False,
              title="solid: whole hemisphere, each\nunmeasured direction taking\nthe least f_r measured "
                    "at\nits θo (exact if diffuse)", title_fontsize=8)
    ax.grid(alpha=0.3)
    ax.set_title(f"{title}\ndirectional albedo (energy conservation at a glance)", fontsize=10)
    return fig


def _runs(x: np.ndarray, mask: np.ndarray) -> list[tuple[float, float]]:
    """The spans of ``x`` (sorted) where ``mask`` holds, each widened to halfway to its neighbours."""
    out = []
    edges = np.concatenate([[x[0]], 0.5 * (x[1:] + x[:-1]), [x[-1]]])
    k = 0
    while k < len(x):
        if mask[k]:
            j = k
            while j + 1 < len(x) and mask[j + 1]:
                j += 1
            out.append((float(edges[k]), float(edges[j + 1])))
            k = j + 1
        else:
            k += 1
    return out


POLAR = PlotKind(lambda b, data, ti, pi: polar_slice(b, _incidences(b, data), pi), _draw_polar)
HEMISPHERE = PlotKind(lambda b, data, ti, pi: hemisphere_slice(b, ti, pi), _draw_hemisphere)
MERL = PlotKind(lambda b, data, ti, pi: merl_slice(b), _draw_merl)
RECIPROCITY = PlotKind(lambda b, data, ti, pi: reciprocity_slice(b, pi), _draw_reciprocity)
ALBEDO = PlotKind(_albedo_slice, _draw_albedo)
