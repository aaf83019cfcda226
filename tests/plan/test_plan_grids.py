"""GRID parsing and enumeration: exact counts against brute force, shortcut pairs, and error messages.

The brute-force counters below are deliberately naive: plain loops over itertools.product on integer
grid indices, with the symmetry classes spelled out as sets of tuples. They share no code with the
vectorized enumeration in gonio.plan.grids.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from gonio.geometry import from_half_diff, merl_bin_centres
from gonio.plan.grids import MAX_POSES, class_members, enumerate_grid, parse_grid, pose_bound


def brute_iso(step, theta_max, reciprocity, mirror):
    n = 0
    while (n + 1) * step <= theta_max + 1e-9:
        n += 1
    thetas = range(n + 1)
    turns = round(360 / step)
    raw = list(itertools.product(thetas, thetas, range(turns)))
    counts = {"grid": len(raw)}
    collapsed = {(a, b, 0 if a == 0 or b == 0 else m) for a, b, m in raw}
    counts["pole_collapse"] = len(collapsed)

    def variants(a, b, m, rec, mir):
        out = {(a, b, m)}
        neg = (-m) % turns
        if rec:
            out.add((b, a, neg))
        if mir:
            out.add((a, b, neg))
        if rec and mir:
            out.add((b, a, m))
        return out

    if reciprocity:
        counts["reciprocity"] = len({min(variants(*p, True, False)) for p in collapsed})
    if mirror:
        counts["mirror"] = len({min(variants(*p, reciprocity, True)) for p in collapsed})
    return counts, {min(variants(*p, reciprocity, mirror)) for p in collapsed}


def brute_full(step, theta_max, reciprocity):
    n = 0
    while (n + 1) * step <= theta_max + 1e-9:
        n += 1
    turns = round(360 / step)
    dirs = list(itertools.product(range(n + 1), range(turns)))
    counts = {"grid": len(dirs) ** 2}
    collapsed = {((a, 0 if a == 0 else p), (b, 0 if b == 0 else q)) for (a, p), (b, q) in
                 itertools.product(dirs, dirs)}
    counts["pole_collapse"] = len(collapsed)
    if reciprocity:
        counts["reciprocity"] = len({frozenset(pair) for pair in collapsed})
    return counts


def brute_merl(stride, theta_max, reciprocity):
    kept = []
    counts = {"grid": 0, "horizon": 0, "theta_max": 0}
    if reciprocity:
        counts["reciprocity"] = 0
    for ih, id_, ip, half in itertools.product(range(0, 90, stride), range(0, 90, stride),
                                               range(0, 180, stride), (0, 1)):
        counts["grid"] += 1
        if reciprocity and half:
            continue
        if reciprocity:
            counts["reciprocity"] += 1
        th, td, pd = (float(x) for x in merl_bin_centres(ih, id_, ip))
        wi, wo = from_half_diff(th, 0.0, td, pd + math.pi * half)
        if wi[2] <= 1e-9 or wo[2] <= 1e-9:
            continue
        counts["horizon"] += 1
        ti, to = math.degrees(math.acos(wi[2])), math.degrees(math.acos(wo[2]))
        if ti > theta_max + 1e-7 or to > theta_max + 1e-7:
            continue
        counts["theta_max"] += 1
        kept.append((tuple(np.round(wi, 9)), tuple(np.round(wo, 9))))
    order = ["grid", "reciprocity", "horizon", "theta_max"] if reciprocity else ["grid", "horizon",
                                                                                  "theta_max"]
    return {k: counts[k] for k in order}, kept


@pytest.mark.parametrize("step", [30, 45, 22.5])
@pytest.mark.parametrize("theta_max", [80, 90, 60])
@pytest.mark.parametrize("reciprocity", [True, False])
@pytest.mark.parametrize("mirror", [True, False])
def test_iso_counts_match_brute_force(step, theta_max, reciprocity, mirror):
    spec = parse_grid(f"iso:step={step},reciprocity={str(reciprocity).lower()},mirror={str(mirror).lower()}")
    grid = enumerate_grid(spec, theta_max)
    want, classes = brute_iso(step, theta_max, reciprocity, mirror)
    assert grid.counts == want
    assert list(grid.counts) == list(want)  # stage order too
    assert len(grid.theta_i) == list(want.values())[-1]
    # The kept poses are exactly one per class, at the class's canonical member.
    got = {(int(a), int(b), int(m)) for a, b, m in grid.loops}
    assert got == classes


@pytest.mark.parametrize("step", [45, 60, 90])
@pytest.mark.parametrize("reciprocity", [True, False])
def test_full_counts_match_brute_force(step, reciprocity):
    grid = enumerate_grid(parse_grid(f"full:step={step},reciprocity={str(reciprocity).lower()}"), 80)
    assert grid.counts == brute_full(step, 80, reciprocity)
    pairs = {((a, p), (b, q)) for a, p, b, q in grid.loops.tolist()}
    assert len(pairs) == len(grid.theta_i)  # no pose twice


@pytest.mark.parametrize("stride", [10, 30, 45])
@pytest.mark.parametrize("reciprocity", [True, False])
def test_merl_counts_match_brute_force(stride, reciprocity):
    grid = enumerate_grid(parse_grid(f"merl:stride={stride},reciprocity={str(reciprocity).lower()}"), 80)
    want, _ = brute_merl(stride, 80, reciprocity)
    assert grid.counts == want


def _dir_key(theta, phi):
    v = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=-1)
    return [tuple(r) for r in np.round(v, 7).tolist()]


@pytest.mark.parametrize("grid", ["full:step=45", "merl:stride=15"])
def test_reciprocity_keeps_one_of_each_pair(grid):
    on = enumerate_grid(parse_grid(grid), 80)
    off = enumerate_grid(parse_grid(grid + ",reciprocity=false"), 80)
    kept = set(zip(_dir_key(on.theta_i, on.phi_i), _dir_key(on.theta_o, on.phi_o), strict=True))
    every = list(zip(_dir_key(off.theta_i, off.phi_i), _dir_key(off.theta_o, off.phi_o), strict=True))
    # Every pose measured without the shortcut is kept, or its swap is; never both (unless equal).
    for wi, wo in every:
        assert ((wi, wo) in kept) != ((wo, wi) in kept) or wi == wo
    assert len(kept) == len(on.theta_i)
    assert {(wi, wo) for wi, wo in every} >= kept


def test_iso_reciprocity_and_mirror_members_are_in_the_full_grid():
    spec = parse_grid("iso:step=30,mirror=true")
    g = enumerate_grid(spec, 80)
    members = class_members(spec, g.theta_i, g.phi_i, g.theta_o, g.phi_o)
    assert len(members) == 3
    off = enumerate_grid(parse_grid("iso:step=30,reciprocity=false"), 80)
    every = {(round(math.degrees(a)), round(math.degrees(b)), round(math.degrees(c)) % 360)
             for a, b, c in zip(off.theta_i, off.theta_o, off.phi_o, strict=True)}
    for ti, pi_, to, po in members:
        assert np.all(pi_ == 0.0)
        got = {(round(math.degrees(a)), round(math.degrees(b)), round(math.degrees(c)) % 360)
               for a, b, c in zip(ti, to, po, strict=True)}
        assert got <= every


def test_normalized_round_trip():
    for text in ["iso:step=2.5", "iso:step=5,mirror=true,reciprocity=false,theta_max=60,order=raster",
                 "full:step=15,order=tour", "merl:stride=4,reciprocity=false", " iso : step = 5 "]:
        spec = parse_grid(text)
        assert parse_grid(spec.normalized) == spec
        assert parse_grid(spec.spelled(70.0, "serpentine")).theta_max_deg == 70.0
    assert parse_grid("iso:step=5").normalized == "iso:step=5,reciprocity=true,mirror=false,order=auto"
    assert parse_grid("iso:step=5").isotropy and not parse_grid("full:step=5").isotropy


@pytest.mark.parametrize("text, message", [
    ("", "expected 'KIND:OPTION=VALUE"),
    ("cube:step=5", "grid kind 'cube' is unknown; allowed: iso, full, merl"),
    ("iso", "grid 'iso': option 'step' is required"),
    ("iso:step=0", "grid 'iso': option 'step' must be > 0 and <= 90 degrees, got 0"),
    ("iso:step=-5", "option 'step' must be > 0 and <= 90 degrees, got -5"),
    ("iso:step=91", "option 'step' must be > 0 and <= 90 degrees, got 91"),
    ("iso:step=7", "grid 'iso': option 'step' must divide 360 degrees evenly"),
    ("iso:step=abc", "grid 'iso': option 'step' must be a finite number, got 'abc'"),
    ("iso:step=nan", "option 'step' must be a finite number"),
    ("iso:step=5,step=10", "grid 'iso': option 'step' given twice"),
    ("iso:step=5,colour=red", "grid 'iso': unknown option 'colour'; allowed: step, theta_max"),
    ("full:step=5,mirror=true", "grid 'full': unknown option 'mirror'"),
    ("iso:step=5,theta_max=95", "grid 'iso': option 'theta_max' must be > 0 and <= 90 degrees, got 95"),
    ("iso:step=5,theta_max=0", "option 'theta_max' must be > 0 and <= 90 degrees, got 0"),
    ("iso:step=5,reciprocity=maybe", "grid 'iso': option 'reciprocity' must be true or false, got 'maybe'"),
    ("iso:step=5,mirror", "grid 'iso': option 'mirror' needs a value"),
    ("iso:step=5,isotropy=false", "grid 'iso': option 'isotropy' must be true"),
    ("full:step=5,isotropy=true", "grid 'full': option 'isotropy' must be false"),
    ("merl:stride=0", "grid 'merl': option 'stride' must be an integer from 1 to 90, got 0"),
    ("merl:stride=2.5", "option 'stride' must be an integer from 1 to 90, got 2.5"),
    ("merl:step=4", "grid 'merl': unknown option 'step'"),
    ("merl:reciprocity=true", "grid 'merl': option 'stride' is required"),
    ("iso:step=5,order=random", "grid 'iso': option 'order' must be one of auto, serpentine, raster, tour"),
])
def test_bad_grid_strings_name_the_field_and_the_range(text, message):
    with pytest.raises(ValueError) as err:
        parse_grid(text)
    assert message in str(err.value)


def test_too_large_a_grid_is_refused_before_it_is_built():
    with pytest.raises(ValueError, match=f"exceed the {MAX_POSES:,} a plan can hold; use a larger 'step'"):
        enumerate_grid(parse_grid("full:step=1"), 80)
    with pytest.raises(ValueError, match="exceed the"):
        enumerate_grid(parse_grid("iso:step=0.25"), 80)
    # Refused from its parameters alone: 4e16 poses, no array of them (it took 70 s and 2.4 GB).
    with pytest.raises(ValueError, match="41,472,000,432,000,001 poses exceed the"):
        enumerate_grid(parse_grid("full:step=0.01"), 80)
    # A step of 1e-300 degrees: a count of about 1e900, said in one short line (it once printed every digit).
    with pytest.raises(ValueError, match=r"'iso': more than 10\^9[0-9][0-9] poses exceed the 3,000,000"):
        enumerate_grid(parse_grid("iso:step=1e-300"), 80)


@pytest.mark.parametrize("grid", ["iso:step=15", "iso:step=10,mirror=true", "iso:step=30,reciprocity=false",
                                  "iso:step=7.5,theta_max=50,reciprocity=false,mirror=true",
                                  "full:step=30", "full:step=45,reciprocity=false",
                                  "full:step=20,theta_max=60",
                                  "merl:stride=15", "merl:stride=30,reciprocity=false", "merl:stride=7"])
def test_the_pose_bound_is_exact_for_lattices_and_bounds_merl_grids(grid):
    spec = parse_grid(grid)
    for tmax in (80.0, 90.0, 45.0):
        tmax = spec.theta_max_deg or tmax
        g = enumerate_grid(spec, tmax)
        n = g.theta_i.size
        if spec.kind == "merl":
            assert list(g.counts.values())[1 if spec.reciprocity else 0] == pose_bound(spec, tmax) >= n
        else:
            assert pose_bound(spec, tmax) == n


def test_theta_max_bounds_the_lattice():
    g = enumerate_grid(parse_grid("iso:step=10,theta_max=45"), 45)
    assert np.degrees(max(g.theta_i.max(), g.theta_o.max())) == pytest.approx(40.0)
    g = enumerate_grid(parse_grid("iso:step=10"), 90)
    assert np.degrees(g.theta_o.max()) == pytest.approx(90.0)
    with pytest.raises(ValueError, match="theta_max_deg: must be > 0 and <= 90"):
        enumerate_grid(parse_grid("iso:step=10"), 120)
