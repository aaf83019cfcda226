"""GRID strings: parsing, validation and enumeration of the poses a campaign measures.

Grammar: ``KIND:OPTION=VALUE[,OPTION=VALUE...]``, spaces ignored, each option at most once. The kinds
(``iso``, ``full``, ``merl``), the poses each measures and the options each takes are the registry
:data:`gonio.registries.GRID_KINDS` (each entry's target a :class:`GridKind` of this module, or of a
plugin); what each option takes, its default and what it does, :data:`gonio.registries.GRID_OPTIONS`
(``gonio plan --help`` writes both out).

Count stages, in order (each the number of poses left after it): ``grid`` (the raw lattice), then
``pole_collapse`` (iso, full: one azimuth where θ = 0), ``reciprocity`` (when on), ``mirror`` (iso, when
on), ``horizon`` and ``theta_max`` (merl: both directions above the horizon and within theta_max).
For merl the raw lattice spans φd over [0, 2π) (both members of each pair), so ``reciprocity`` halves it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from gonio.geometry import MERL_SHAPE, from_half_diff_grid, merl_bin_centres, vec_to_sph
from gonio.registries import GRID_KINDS, ORDERS

__all__ = ["GridSpec", "GridPoses", "GridKind", "parse_grid", "enumerate_grid", "pose_bound",
           "check_pose_bound", "class_members", "grid_kind", "MAX_POSES", "ADAPTIVE_MAX_POSES",
           "ADAPTIVE_MAX_BUDGET_S", "ISO", "FULL", "MERL", "ADAPTIVE"]

#: A plan holds at most this many poses (memory and time stay within a workstation's reach).
MAX_POSES = 3_000_000
#: An adaptive campaign's largest pose budget (each round fits the samples so far: O(N) per round).
ADAPTIVE_MAX_POSES = 100_000
#: An adaptive campaign's largest time budget: 30 days of gantry time.
ADAPTIVE_MAX_BUDGET_S = 30 * 86_400.0
_BOOLS = {"true": True, "false": False}
# Tolerance on "step divides 360" and on θ <= theta_max for values that come from decimal degrees.
_DIV_TOL = 1e-9
_ANGLE_TOL = 1e-9


@dataclass(frozen=True)
class GridSpec:
    """A validated GRID string (see the module docstring).

    Attributes
    ----------
    kind : str
        A name of :data:`gonio.registries.GRID_KINDS` (``"iso"``, ``"full"``, ``"merl"``, ...).
    step_deg : float or None
        Lattice step in degrees (iso, full).
    stride : int or None
        MERL bin stride (merl).
    theta_max_deg : float or None
        Largest θi, θo in degrees; None means the config's ``kinematics.theta_max_deg``.
    reciprocity, mirror : bool
        Which shortcuts are on.
    order : str
        A name of :data:`gonio.registries.ORDERS` (``"auto"``, ``"serpentine"``, ``"raster"``, ...).
    """

    kind: str
    step_deg: float | None = None
    stride: int | None = None
    theta_max_deg: float | None = None
    reciprocity: bool = True
    mirror: bool = False
    order: str = "auto"
    poses: int | None = None
    budget_s: float | None = None
    anisotropic: bool = False

    @property
    def isotropy(self) -> bool:
        """True for iso and merl grids and adaptive ones without ``anisotropic=true`` (measured assuming
        an isotropic sample)."""
        return grid_kind(self.kind).isotropic and not self.anisotropic

    @property
    def normalized(self) -> str:
        """The GRID string with every option spelled out in a fixed order (``theta_max`` only when
        given); it parses back to the same spec."""
        return self.spelled()

    def spelled(self, theta_max_deg: float | None = None, order: str | None = None) -> str:
        """:attr:`normalized`, with ``theta_max`` and ``order`` resolved to the values a plan used."""
        tmax = self.theta_max_deg if theta_max_deg is None else theta_max_deg
        if self.poses is not None or self.budget_s is not None:
            parts = [f"poses={self.poses}" if self.poses is not None else f"budget_s={_num(self.budget_s)}"]
        else:
            parts = [f"step={_num(self.step_deg)}"] if self.stride is None else [f"stride={self.stride}"]
        if tmax is not None:
            parts.append(f"theta_max={_num(tmax)}")
        if "reciprocity" in _options(self.kind):
            parts.append(f"reciprocity={str(self.reciprocity).lower()}")
        if "mirror" in _options(self.kind):
            parts.append(f"mirror={str(self.mirror).lower()}")
        if self.anisotropic:
            parts.append("anisotropic=true")
        parts.append(f"order={order or self.order}")
        return f"{self.kind}:" + ",".join(parts)


@dataclass(frozen=True)
class GridPoses:
    """Poses of a grid after the symmetry shortcuts, before feasibility.

    Attributes
    ----------
    theta_i, phi_i, theta_o, phi_o : ndarray, shape (P,)
        Radians; φ in [0, 2π) and 0 where θ = 0.
    loops : ndarray of int64, shape (P, L)
        Each pose's indices in the grid's natural loops, outer first (θi, θo, Δφ for iso; θi, φi, θo,
        φo for full; θh, θd, φd bins for merl): the input of serpentine and raster orders.
    counts : dict of str to int
        Poses left after each stage, in order (see the module docstring).
    """

    theta_i: np.ndarray
    phi_i: np.ndarray
    theta_o: np.ndarray
    phi_o: np.ndarray
    loops: np.ndarray
    counts: dict[str, int]


@dataclass(frozen=True)
class GridKind:
    """What a grid kind measures and what the planner asks of it (the target of a
    :data:`gonio.registries.GRID_KINDS` entry; the entry's ``options`` and ``size`` say what its GRID
    string takes).

    Attributes
    ----------
    enumerate : callable
        ``enumerate(spec, theta_max_deg) -> GridPoses``: the poses after the symmetry shortcuts.
    bound : callable
        ``bound(spec, theta_max_deg) -> int``: the poses it keeps, counted from its parameters alone (an
        upper bound where the exact count needs the poses), so that a huge grid is refused at once.
    isotropic : bool
        Measured assuming an isotropic sample (the ``isotropy`` option must say so).
    members : callable, optional
        ``members(spec, theta_i, phi_i, theta_o, phi_o)``: the other poses the shortcuts identify with
        each pose (:func:`class_members`); default: the Helmholtz partner when reciprocity is on.
    rows : callable, optional
        ``rows(spec, loops) -> (loops, period)``: the loops a serpentine sweeps, the innermost an azimuth
        of ``period`` steps around the turn, for a lattice whose lines a sweep can follow (fly scans,
        cut serpentines); None: scattered points, whose loops are taken as they are.
    auto : str
        What ``order=auto`` plans: ``"serpentine"``, ``"tour"``, or ``"quicker"`` (both, keeping the
        quicker, up to ``AUTO_TOUR_MAX_POSES`` poses: :mod:`gonio.plan.build`).
    campaign : str, optional
        The campaign kind (:data:`gonio.units.KINDS`) of a grid whose poses are not all known when it is
        planned (``adaptive``: rounds placed from what was measured); None: a fixed plan (stop-and-go,
        or fly with ``order=fly``).
    """

    enumerate: Callable
    bound: Callable
    isotropic: bool
    members: Callable | None = None
    rows: Callable | None = None
    auto: str = "serpentine"
    campaign: str | None = None


def grid_kind(name: str) -> GridKind:
    """The :class:`GridKind` registered as ``name`` (ValueError naming the allowed kinds)."""
    return GRID_KINDS.check(name, "grid kind").load()


def _options(kind: str) -> tuple[str, ...]:
    return tuple(GRID_KINDS[kind].extra["options"])


def parse_grid(grid: str) -> GridSpec:
    """Parse and validate a GRID string.

    Raises
    ------
    ValueError
        Naming the kind, the option and what is allowed, e.g. ``grid 'iso': option 'step' must be
        > 0 and <= 90 degrees, got 0``.

    Examples
    --------
    >>> parse_grid("iso:step=5,mirror=true").normalized
    'iso:step=5,reciprocity=true,mirror=true,order=auto'
    """
    kinds = GRID_KINDS.names()
    if not isinstance(grid, str) or not grid.strip():
        raise ValueError(f"grid: expected 'KIND:OPTION=VALUE,...' with KIND one of {', '.join(kinds)}; "
                         f"got {grid!r}")
    text = "".join(grid.split())
    kind, _, rest = text.partition(":")
    if kind not in kinds:
        raise ValueError(f"grid kind '{kind}' is unknown; allowed: {', '.join(kinds)}")
    allowed = _options(kind)
    raw: dict[str, str] = {}
    for item in filter(None, rest.split(",")):
        key, eq, value = item.partition("=")
        if key not in allowed:
            raise ValueError(f"grid '{kind}': unknown option '{key}'; allowed: {', '.join(allowed)}")
        if not eq or not value:
            raise ValueError(f"grid '{kind}': option '{key}' needs a value ({key}=...)")
        if key in raw:
            raise ValueError(f"grid '{kind}': option '{key}' given twice")
        raw[key] = value
    fields: dict[str, object] = {"kind": kind}
    if GRID_KINDS[kind].extra["size"] == "budget":
        fields.update(_parse_budget(kind, raw))
    elif GRID_KINDS[kind].extra["size"] == "stride":
        if "stride" not in raw:
            raise ValueError(f"grid '{kind}': option 'stride' is required (an integer from 1 to 90)")
        stride = _parse_number(kind, "stride", raw["stride"])
        if stride != int(stride) or not 1 <= stride <= 90:
            raise ValueError(f"grid '{kind}': option 'stride' must be an integer from 1 to 90, got "
                             f"{raw['stride']}")
        fields["stride"] = int(stride)
    else:
        if "step" not in raw:
            raise ValueError(f"grid '{kind}': option 'step' is required (degrees, > 0 and <= 90, "
                             "dividing 360)")
        step = _parse_number(kind, "step", raw["step"])
        if not 0.0 < step <= 90.0:
            raise ValueError(f"grid '{kind}': option 'step' must be > 0 and <= 90 degrees, got {raw['step']}")
        turns = 360.0 / step
        if abs(turns - round(turns)) > _DIV_TOL * turns:
            raise ValueError(f"grid '{kind}': option 'step' must divide 360 degrees evenly (e.g. 1, 2.5, 5, "
                             f"15), got {raw['step']}")
        fields["step_deg"] = step
    if "theta_max" in raw:
        tmax = _parse_number(kind, "theta_max", raw["theta_max"])
        if not 0.0 < tmax <= 90.0:
            raise ValueError(f"grid '{kind}': option 'theta_max' must be > 0 and <= 90 degrees, got "
                             f"{raw['theta_max']}")
        fields["theta_max_deg"] = tmax
    for key in ("reciprocity", "mirror", "anisotropic"):
        if key in raw:
            fields[key] = _parse_bool(kind, key, raw[key])
    if "isotropy" in raw:
        iso = _parse_bool(kind, "isotropy", raw["isotropy"])
        isotropic = grid_kind(kind).isotropic and not fields.get("anisotropic", False)
        if iso != isotropic and fields.get("anisotropic"):
            raise ValueError(f"grid '{kind}': option 'isotropy' must be false with anisotropic=true")
        if iso != isotropic:
            raise ValueError(
                f"grid '{kind}': option 'isotropy' must be false (use 'iso' for isotropic samples)"
                if not isotropic else
                f"grid '{kind}': option 'isotropy' must be true ('{kind}' grids assume an isotropic "
                "sample; use 'full' for anisotropic ones)")
    if "order" in raw:
        orders = ORDERS.names()
        if raw["order"] not in orders:
            raise ValueError(f"grid '{kind}': option 'order' must be one of {', '.join(orders)}, got "
                             f"'{raw['order']}'")
        if ORDERS[raw["order"]].extra.get("lattice") and grid_kind(kind).campaign == "adaptive":
            raise ValueError(f"grid '{kind}': option 'order={raw['order']}' needs lines of a lattice to "
                             "sweep; no round of an adaptive grid can fly (its poses are scattered): use "
                             "order=auto or tour")
        if ORDERS[raw["order"]].extra.get("lattice") and grid_kind(kind).rows is None:
            raise ValueError(f"grid '{kind}': option 'order={raw['order']}' needs lines of a lattice to "
                             "sweep; use an iso or full grid")
        fields["order"] = raw["order"]
    return GridSpec(**fields)


def _parse_budget(kind: str, raw: dict[str, str]) -> dict[str, object]:
    """``poses=N`` or ``budget_s=T``, exactly one (an adaptive grid's budget)."""
    given = [k for k in ("poses", "budget_s") if k in raw]
    if len(given) != 1:
        raise ValueError(f"grid '{kind}': give exactly one of 'poses' (an integer from 1 to "
                         f"{ADAPTIVE_MAX_POSES:,}) or 'budget_s' (seconds of gantry time, > 0 and <= "
                         f"{ADAPTIVE_MAX_BUDGET_S:,.0f}); got {' and '.join(given) or 'neither'}")
    value = _parse_number(kind, given[0], raw[given[0]])
    if given[0] == "poses":
        if value != int(value) or not 1 <= value <= ADAPTIVE_MAX_POSES:
            raise ValueError(f"grid '{kind}': option 'poses' must be an integer from 1 to "
                             f"{ADAPTIVE_MAX_POSES:,}, got {raw['poses']}")
        return {"poses": int(value)}
    if not 0.0 < value <= ADAPTIVE_MAX_BUDGET_S:
        raise ValueError(f"grid '{kind}': option 'budget_s' must be > 0 and <= {ADAPTIVE_MAX_BUDGET_S:,.0f} "
                         f"seconds, got {raw['budget_s']}")
    return {"budget_s": value}


def enumerate_grid(spec: GridSpec, theta_max_deg: float) -> GridPoses:
    """The poses of ``spec`` with θ up to ``theta_max_deg`` after the symmetry shortcuts.

    Raises
    ------
    ValueError
        When the grid would hold more than :data:`MAX_POSES` poses.
    """
    check_pose_bound(spec, theta_max_deg)
    return grid_kind(spec.kind).enumerate(spec, theta_max_deg)


def pose_bound(spec: GridSpec, theta_max_deg: float) -> int:
    """The poses ``spec`` keeps up to ``theta_max_deg``, from its parameters alone (nothing is built, so
    it answers at once even for ``full:step=0.01``): exact for iso and full grids; for merl grids the
    lattice after reciprocity, an upper bound (the horizon and theta_max cut it further).

    Examples
    --------
    >>> pose_bound(parse_grid("iso:step=30"), 90), enumerate_grid(parse_grid("iso:step=30"), 90).theta_i.size
    (61, 61)
    >>> f"{pose_bound(parse_grid('full:step=0.01'), 80):.3g}"
    '4.15e+16'
    """
    if not 0.0 < theta_max_deg <= 90.0:
        raise ValueError(f"theta_max_deg: must be > 0 and <= 90 degrees, got {theta_max_deg}")
    return int(grid_kind(spec.kind).bound(spec, theta_max_deg))


def class_members(spec: GridSpec, theta_i, phi_i, theta_o, phi_o) -> list[tuple[np.ndarray, ...]]:
    """The other poses that the shortcuts of ``spec`` identify with each given pose.

    A plan measures one pose per class; when the kept one cannot be reached, another member may be.
    Iso members are rotated back to φi = 0 (isotropy makes the absolute azimuth irrelevant).

    Returns
    -------
    list of (theta_i, phi_i, theta_o, phi_o)
        One tuple of (P,) arrays per alternative member; empty when no shortcut is on.
    """
    ti, pi_, to, po = (np.asarray(a, dtype=np.float64) for a in (theta_i, phi_i, theta_o, phi_o))
    members = grid_kind(spec.kind).members
    if members is not None:
        return members(spec, ti, pi_, to, po)
    return [(to, po, ti, pi_)] if spec.reciprocity else []


def _iso_members(spec: GridSpec, ti, pi_, to, po) -> list[tuple[np.ndarray, ...]]:
    two_pi = 2.0 * np.pi
    out: list[tuple[np.ndarray, ...]] = []
    dphi = np.mod(po - pi_, two_pi)
    neg = np.mod(-dphi, two_pi)
    zero = np.zeros_like(ti)
    if spec.reciprocity:
        out.append((to, zero, ti, _pole(ti, neg)))
    if spec.mirror:
        out.append((ti, zero, to, _pole(to, neg)))
    if spec.reciprocity and spec.mirror:
        out.append((to, zero, ti, _pole(ti, dphi)))
    return out


def _pole(theta, phi):
    return np.where(theta <= _ANGLE_TOL, 0.0, phi)


def _iso(spec: GridSpec, theta_max_deg: float) -> GridPoses:
    step = spec.step_deg
    n = _theta_count(step, theta_max_deg)
    turns = round(360.0 / step)
    idx = [np.arange(k, dtype=np.int32) for k in (n, n, turns)]
    a, b, m = np.meshgrid(*idx, indexing="ij")
    a, b, m = a.ravel(), b.ravel(), m.ravel()
    counts = {"grid": a.size}
    keep = ((a > 0) & (b > 0)) | (m == 0)
    counts["pole_collapse"] = int(keep.sum())
    if spec.reciprocity:
        # (θi, θo, Δφ) ~ (θo, θi, −Δφ): keep θi < θo, and Δφ <= 180° when θi = θo.
        keep &= (a < b) | ((a == b) & (2 * m <= turns))
        counts["reciprocity"] = int(keep.sum())
    if spec.mirror:
        keep &= 2 * m <= turns
        counts["mirror"] = int(keep.sum())
    a, b, m = a[keep], b[keep], m[keep]
    rad = np.radians(step)
    theta_i, theta_o = a * rad, b * rad
    phi_o = np.where(b > 0, m * rad, 0.0)
    return GridPoses(theta_i, np.zeros_like(theta_i), theta_o, phi_o,
                     np.stack([a, b, m], axis=1).astype(np.int64), counts)


def _full(spec: GridSpec, theta_max_deg: float) -> GridPoses:
    step = spec.step_deg
    n = _theta_count(step, theta_max_deg)
    turns = round(360.0 / step)
    # Directions in lexicographic (θ, φ) order, the pole once: what canonical_reciprocal compares.
    da = np.concatenate([[0], np.repeat(np.arange(1, n), turns)])
    dp = np.concatenate([[0], np.tile(np.arange(turns), n - 1)])
    nd = da.size
    counts = {"grid": (n * turns) ** 2, "pole_collapse": nd * nd}
    if spec.reciprocity:
        counts["reciprocity"] = nd * (nd + 1) // 2
        i, j = np.triu_indices(nd)
    else:
        i, j = (x.ravel() for x in np.meshgrid(np.arange(nd), np.arange(nd), indexing="ij"))
    rad = np.radians(step)
    return GridPoses(da[i] * rad, dp[i] * rad, da[j] * rad, dp[j] * rad,
                     np.stack([da[i], dp[i], da[j], dp[j]], axis=1).astype(np.int64), counts)


def _merl(spec: GridSpec, theta_max_deg: float) -> GridPoses:
    k = spec.stride
    nh, nd, nphi = MERL_SHAPE
    # φd and φd + π are the two members of a Helmholtz pair (ωi and ωo swapped): with reciprocity only
    # [0, π) is kept, so only that half is made.
    halves = 1 if spec.reciprocity else 2
    ih, id_, ip, half = np.meshgrid(np.arange(0, nh, k), np.arange(0, nd, k), np.arange(0, nphi, k),
                                    np.arange(halves), indexing="ij")
    ih, id_, ip, half = ih.ravel(), id_.ravel(), ip.ravel(), half.ravel()
    counts = {"grid": ih.size * 2 // halves}
    keep = np.ones(ih.size, dtype=bool)
    if spec.reciprocity:
        counts["reciprocity"] = int(keep.sum())
    # the bins' directions, computed per grid line (the same numbers as from_half_diff of every point)
    theta_h, theta_d, phi_d = merl_bin_centres(*(np.arange(0, n, k) for n in MERL_SHAPE))
    wi, wo = (w.reshape(-1, 3) for w in
              from_half_diff_grid(theta_h, theta_d, (phi_d[:, None] + np.pi * np.arange(halves)).reshape(-1)))
    keep &= (wi[:, 2] > _ANGLE_TOL) & (wo[:, 2] > _ANGLE_TOL)
    counts["horizon"] = int(keep.sum())
    theta_i, phi_i = vec_to_sph(wi)
    theta_o, phi_o = vec_to_sph(wo)
    tmax = np.radians(theta_max_deg) + _ANGLE_TOL
    keep &= (theta_i <= tmax) & (theta_o <= tmax)
    counts["theta_max"] = int(keep.sum())
    loops = np.stack([ih, id_, ip + nphi * half], axis=1)[keep].astype(np.int64)
    return GridPoses(theta_i[keep], phi_i[keep], theta_o[keep], phi_o[keep], loops, counts)


def _iso_bound(spec: GridSpec, theta_max_deg: float) -> int:
    n = _theta_count(spec.step_deg, theta_max_deg)
    return _iso_size(n, round(360.0 / spec.step_deg), spec.reciprocity, spec.mirror)


def _full_bound(spec: GridSpec, theta_max_deg: float) -> int:
    n = _theta_count(spec.step_deg, theta_max_deg)
    nd = 1 + (n - 1) * round(360.0 / spec.step_deg)   # directions, the pole once
    return nd * (nd + 1) // 2 if spec.reciprocity else nd * nd


def _merl_bound(spec: GridSpec, theta_max_deg: float) -> int:
    k = spec.stride
    nh, nd, nphi = MERL_SHAPE
    return -(-nh // k) * -(-nd // k) * -(-nphi // k) * (1 if spec.reciprocity else 2)


def _iso_rows(spec: GridSpec, loops: np.ndarray) -> tuple[np.ndarray, int]:
    return loops, round(360.0 / spec.step_deg)


def _adaptive_members(spec: GridSpec, ti, pi_, to, po) -> list[tuple[np.ndarray, ...]]:
    """An adaptive grid's pose stands for its Helmholtz twin: rotated to φi = 0 (isotropic), or as it is
    with ``anisotropic=true``."""
    return [(to, po, ti, pi_)] if spec.anisotropic else _iso_members(spec, ti, pi_, to, po)


def _full_rows(spec: GridSpec, loops: np.ndarray) -> tuple[np.ndarray, int]:
    """Full grids loop over θi, θo, Δφ and, innermost, φi (with φo = φi + Δφ): rows turn the whole
    configuration about the normal (φi and φo together, Δφ fixed): one rotation stage on a
    sample-stage gantry, both carriages in step on a two-arm one, which then never meet inside a row."""
    period = round(360.0 / spec.step_deg)
    a_i, p_i, a_o, p_o = loops.T
    return np.stack([a_i, a_o, (p_o - p_i) % period, p_i], axis=1), period


def _adaptive(spec: GridSpec, theta_max_deg: float) -> GridPoses:
    raise ValueError(f"grid '{spec.kind}': its poses are placed as it measures; plan it as a campaign "
                     "(gonio.campaign.plan_campaign, gonio plan)")


def _adaptive_bound(spec: GridSpec, theta_max_deg: float) -> int:
    # A time budget's pose count is known once the pilot is planned (gonio.adaptive.plan): 0 here.
    return spec.poses or 0


ISO = GridKind(enumerate=_iso, bound=_iso_bound, isotropic=True, members=_iso_members, rows=_iso_rows,
               auto="quicker")
#: Adaptive acquisition (:mod:`gonio.adaptive`): a pilot lattice, then rounds placed from the samples.
#: Its plans are made of given poses (:func:`gonio.plan.build.build_plan` ``poses=``); reciprocity is
#: always on (a round's pose stands for its Helmholtz twin, which is measured where only it is reachable).
ADAPTIVE = GridKind(enumerate=_adaptive, bound=_adaptive_bound, isotropic=True, members=_adaptive_members,
                    auto="tour", campaign="adaptive")
FULL = GridKind(enumerate=_full, bound=_full_bound, isotropic=False, rows=_full_rows)
MERL = GridKind(enumerate=_merl, bound=_merl_bound, isotropic=True, auto="tour")


def _iso_size(n: int, turns: int, reciprocity: bool, mirror: bool) -> int:
    """Poses an iso grid keeps, counted without building it (to refuse huge grids up front)."""
    arc = turns // 2 + 1 if mirror else turns  # Δφ values kept off the pole
    if not reciprocity:
        return (n - 1) ** 2 * arc + 2 * n - 1
    half = turns // 2 + 1  # Δφ <= 180° where θi = θo
    return (n - 1) * (n - 2) // 2 * arc + (n - 1) * half + n


def _theta_count(step: float, theta_max_deg: float) -> int:
    return int(np.floor(theta_max_deg / step + _DIV_TOL)) + 1


def check_pose_bound(spec: GridSpec, theta_max_deg: float, limit: int = MAX_POSES,
                     holder: str = "a plan can hold") -> None:
    """ValueError naming the option to change when :func:`pose_bound` exceeds ``limit``."""
    n = pose_bound(spec, theta_max_deg)
    if n > limit:
        opt = "stride" if spec.stride is not None else "step"
        at_most = "" if spec.stride is None else "up to "
        count = f"{n:,}" if n < 10**18 else f"more than 10^{len(str(n)) - 1}"   # one line, not 300 digits
        raise ValueError(f"grid '{spec.kind}': {at_most}{count} poses exceed the {limit:,} {holder}; use a "
                         f"larger '{opt}' or a smaller 'theta_max'")


def _parse_number(kind: str, key: str, text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not np.isfinite(value):
        raise ValueError(f"grid '{kind}': option '{key}' must be a finite number, got '{text}'")
    return value


def _parse_bool(kind: str, key: str, text: str) -> bool:
    if text.lower() not in _BOOLS:
        raise ValueError(f"grid '{kind}': option '{key}' must be true or false, got '{text}'")
    return _BOOLS[text.lower()]


def _num(x: float | None) -> str:
    return "none" if x is None else format(float(x), ".12g")
