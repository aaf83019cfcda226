"""Adaptive against uniform acquisition at equal pose counts (issue 23): where the poses go, nothing else.

For each material, both acquisitions measure the same thing at their poses: the material's own noise-free
f_r (``gonio.sim.materials.load(spec).eval``), on the default simulated gantry (``config/sim.toml``: its
reach, the 5° occlusion cone around retro-reflection, θ <= 80°). Uniform poses are those an
``iso:step=S`` plan measures (:func:`gonio.plan.grids.enumerate_grid`, a reciprocal twin standing in for
an unreachable pose, unreachable classes dropped); the adaptive run (:func:`gonio.adaptive.acquire`) gets
exactly as many poses. Error: cosine-weighted relative L1 against the true material at ``--pairs`` random
direction pairs (:mod:`gonio.adaptive.error`; pairs with both θ <= 80°, seeded).

Columns: the uniform grid through ``gonio.brdf`` (its lattice engine: what a campaign's users get
today; a pair it leaves NaN counts as 0, its coverage is printed), the uniform grid through the
adaptive package's reconstruction (:class:`gonio.adaptive.LocalFit`, log-quadric), the adaptive run
through that same reconstruction, and the ratios. ``same/adaptive`` is the comparison of placement
alone (one engine for both).

``--reach`` also finds the poses adaptive needs to reach the ``iso:step=5`` error (budgets grow by 25 %
from ``--reach-from`` until the adaptive error is at or below the target; the first such budget is
printed). ``--engines`` scores reconstruction variants on the uniform and adaptive samples;
``--pilots`` compares pilot fractions and round growths.

``--campaigns`` runs whole simulated campaigns instead (``gonio simulate`` in this process: the simulated
detector's aperture and noise, the planned tours, checkpoints and the engine): per step, ``iso:step=S``,
then ``adaptive:poses=N`` with its pose count N and ``adaptive:budget_s=T`` with its gantry time T, each
read through ``gonio.brdf`` as users read it (``auto``: the lattice engine for iso, ``local`` for
adaptive), with the gantry time each took (the campaign clock) and the wall time of the simulation.

``--reach-time`` runs whole campaigns too: ``iso:step=5`` (its error through ``gonio.brdf`` is the target),
then ``adaptive:budget_s=T`` for T from ``--reach-from-s`` up by 25 % until the error is at or below the
target, once per ``--variants`` entry: ``before`` (motion ignored, a checkpoint closing every round: the
campaigns of the first adaptive release), ``motion`` (a pose's gantry time in its worth,
:data:`gonio.adaptive.plan.MOTION_WEIGHT`), ``checkpoints`` (checkpoints as needed,
:data:`gonio.adaptive.plan.CHECKPOINTS_AS_NEEDED`), ``both`` (today's default). The gantry time to
the target is interpolated between the last two campaigns (log error against log gantry time), and each
campaign's poses, gantry time and error are printed. ``--campaigns`` takes ``--variants`` too.

``--aniso`` is the panel's anisotropic row (default material: anisotropic Ward, α 0.1 by 0.3): uniform
``full:step=S`` grids (``--steps``, default 30,20; reciprocity only, a twin standing in for an
unreachable pose) against ``acquire(..., anisotropic=True)`` at their pose counts, the uniform grid through
``gonio.brdf`` (its default engine for a ``full`` grid) and both through the 4D reconstruction
(:class:`gonio.adaptive.LocalFit` in the ``pair`` domain). ``--aniso --pilots`` compares the pilot (the
``full:step=S`` grid against the specular plane swept over φi). ``--aniso --campaigns`` runs whole
campaigns as ``--campaigns`` does, ``full:step=S`` and the adaptive ones with ``anisotropic=true``.

``--measured`` is the panel's measured row: a ``bsdf:`` material made as a user makes one (a whole
simulated ``--measured-grid`` campaign, default ``iso:step=5``, of the ``--measured`` material, default
ggx α = 0.1 gold, exported by ``gonio.export`` as a ``bsdf`` tensor file in a temporary folder), then the
default rows (or ``--campaigns``) for ``bsdf:THAT_FILE``, scored against that file's own evaluation. The
file is not exactly reciprocal, and every reconstruction here is (a sample stands for its twin too): the
error of (f(ωi, ωo) + f(ωo, ωi)) / 2, the floor of any reciprocal reconstruction, is printed.

``--export`` (ggx materials with a conductor Fresnel) runs whole campaigns, ``iso:step=5`` and
``adaptive:poses=N`` for each of ``--budgets``, exports each as a ``bsdf`` tensor file and scores the file
as Mitsuba 3 reads it (the ``measured`` plugin, ``llvm_ad_rgb``) against Mitsuba's own ``roughconductor``
with the material's α, η and k: Σ|a − b| / Σ b of f·cos θo over the random pairs. It also scores the
file's NDF against the analytic GGX D (relative L1 weighted by cos θm) and, for each adaptive campaign,
the NDF estimators the export could use (the measured samples within θd of retro-reflection, or the
reconstruction's f̂(ω, ω)) and what the file's error would be with each.

    .venv/bin/python tools/bench_adaptive.py                       # ggx α = 0.2, 148 and 1,156 poses
    .venv/bin/python tools/bench_adaptive.py --full                # the isotropic panel, 4 counts, --reach
    .venv/bin/python tools/bench_adaptive.py --campaigns --steps 20,10   # whole simulated campaigns
    .venv/bin/python tools/bench_adaptive.py --export --budgets 600,1156,2299   # bsdf files in Mitsuba
    .venv/bin/python tools/bench_adaptive.py --reach-time --variants before,motion,checkpoints,both
    .venv/bin/python tools/bench_adaptive.py --measured            # bsdf: of a ggx α = 0.1 campaign
    .venv/bin/python tools/bench_adaptive.py --measured --campaigns   # the same as whole campaigns
    .venv/bin/python tools/bench_adaptive.py --aniso               # anisotropic Ward, full:step=30,20
    .venv/bin/python tools/bench_adaptive.py --aniso --campaigns   # the same as whole campaigns
"""

from __future__ import annotations

import argparse
import contextlib
import os
import platform
import time

import numpy as np

from gonio.adaptive import Samples, acquire, material_measure, random_pairs, reachable_iso, weighted_l1
from gonio.adaptive.pilot import pair_lattice
from gonio.adaptive.reach import reachable_pair
from gonio.adaptive.reconstruct import LocalFit
from gonio.config import load_config
from gonio.geometry import to_isotropic
from gonio.kinematics import make_kinematics
from gonio.plan.grids import enumerate_grid, parse_grid
from gonio.sim.materials import load

#: Rec. 709 luminance of R, G, B.
LUMA = (0.2126, 0.7152, 0.0722)
ANISO = "ward:rho_d=0.1,rho_s=0.05,alpha_x=0.1,alpha_y=0.3"
PANEL = ("ggx:alpha=0.05,metal=gold", "ggx:alpha=0.2,metal=gold",
         "cook-torrance:d=beckmann,m=0.3,metal=gold", "ggx:alpha=0.2,metal=gold,rho_d=0.2,rho_s=0.8")


def uniform_samples(step: float, kin, theta_max: float, measure) -> Samples:
    """The reachable poses of ``iso:step=S`` up to theta_max, measured."""
    grid = enumerate_grid(parse_grid(f"iso:step={step:g}"), np.degrees(theta_max))
    poses = to_isotropic(grid.theta_i, grid.phi_i, grid.theta_o, grid.phi_o)
    ok, (ti, _, to, po) = reachable_iso(kin, *poses, theta_max)
    ti, to, po = ti[ok], to[ok], po[ok]
    return Samples(ti, to, po, measure(ti, to, po))


def lattice_error(samples: Samples, step: float, truth, wi, wo) -> tuple[float, float]:
    """Error and coverage of the uniform samples through gonio.brdf's default (lattice) engine."""
    from gonio.brdf import MeasuredBRDF
    from gonio.dataset import SampledBRDF

    deg = [np.degrees(a) for a in (samples.theta_i, np.zeros(len(samples)), samples.theta_o, samples.dphi)]
    data = SampledBRDF(*deg, value=samples.value, stddev=np.zeros_like(samples.value),
                       attrs={"symmetries": {"reciprocity": True, "isotropy": True, "mirror": False},
                              "grid": f"iso:step={step:g}"})
    return weighted_l1(MeasuredBRDF(data).eval(wi, wo).value, truth, wi, wo)


def adaptive_error(measure, kin, theta_max, budget, truth, wi, wo, **options) -> tuple[float, Samples]:
    acq = acquire(measure, kin, theta_max, budget, **options)
    return weighted_l1(LocalFit(acq.samples).eval(wi, wo), truth, wi, wo)[0], acq


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--materials", help="';'-separated MATERIAL strings (default: ggx α = 0.2 gold; "
                        "--full: the isotropic panel)")
    parser.add_argument("--steps", default=None, help="uniform iso steps, comma-separated (default 20,10; "
                        "--full: 20,10,8,5)")
    parser.add_argument("--full", action="store_true", help="the whole isotropic panel, 4 counts, --reach")
    parser.add_argument("--reach", action="store_true", help="poses adaptive needs for the iso:step=5 error")
    parser.add_argument("--reach-from", type=int, default=100)
    parser.add_argument("--engines", action="store_true", help="reconstruction variants (1,156 poses)")
    parser.add_argument("--pilots", action="store_true", help="pilot fractions and growths (1,156 poses)")
    parser.add_argument("--campaigns", action="store_true", help="whole simulated campaigns through "
                        "gonio.brdf, at equal poses and equal gantry time")
    parser.add_argument("--export", action="store_true", help="bsdf exports of iso:step=5 and adaptive "
                        "campaigns, read by Mitsuba 3, against its roughconductor")
    parser.add_argument("--budgets", default="600,1156,2299", help="adaptive pose counts of --export")
    parser.add_argument("--reach-time", action="store_true", help="gantry time adaptive campaigns need for "
                        "the iso:step=5 campaign's error, per motion weight")
    parser.add_argument("--reach-from-s", type=float, default=200.0)
    parser.add_argument("--variants", default=None, help="comma-separated of before, motion, checkpoints, "
                        "both: how --campaigns and --reach-time place poses and checkpoints (default: both)")
    parser.add_argument("--aniso", action="store_true", help="the anisotropic row: full:step=S against "
                        "adaptive anisotropic=true (default: anisotropic Ward, steps 30,20)")
    parser.add_argument("--measured", nargs="?", const="ggx:alpha=0.1,metal=gold", default=None,
                        metavar="MATERIAL", help="the measured row: bsdf: of the bsdf export of a simulated "
                        "campaign of MATERIAL (default ggx α = 0.1 gold)")
    parser.add_argument("--measured-grid", default="iso:step=5", help="the campaign --measured exports")
    parser.add_argument("--pairs", type=int, default=20_000)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()

    specs = args.materials.split(";") if args.materials else (
        [ANISO] if args.aniso else list(PANEL) if args.full else [PANEL[1]])
    steps = [float(s) for s in (args.steps or ("30,20" if args.aniso else "20,10,8,5" if args.full
                                                else "20,10")).split(",")]
    if args.measured:
        try:
            specs = [_measured_file(args.measured, args.measured_grid)]
        except ValueError as exc:
            parser.error(f"--measured/--measured-grid: {exc}")
    reach = args.reach or args.full
    cfg = load_config()
    kin = make_kinematics(cfg)
    theta_max = np.radians(cfg.kinematics.theta_max_deg)
    wi, wo = random_pairs(args.pairs, theta_max, args.seed)
    print(f"bench_adaptive: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs; "
          f"{args.pairs:,} pairs (seed {args.seed}), θ <= {cfg.kinematics.theta_max_deg:g}°, gantry "
          f"{cfg.name}; " + ("whole simulated campaigns (the simulated detector: aperture, noise)"
                               if args.campaigns or args.export or args.reach_time
                               else "noise-free f_r at the poses"))
    for spec in specs:
        material = load(spec)
        measure = material_measure(material)
        truth = material.eval(wi, wo)
        print(f"\n{spec}")
        if args.measured:
            swapped = material.eval(wo, wi)
            gap = weighted_l1(swapped, truth, wi, wo)[0]
            floor = weighted_l1((truth + swapped) / 2, truth, wi, wo)[0]
            print(f"  not reciprocal: f(ωo, ωi) against f(ωi, ωo) {gap:.4f}; floor of a reciprocal "
                  f"reconstruction, (f + swapped) / 2: {floor:.4f}", flush=True)
        if args.engines:
            _engines(measure, kin, theta_max, truth, wi, wo)
            continue
        if args.aniso and args.campaigns:
            _campaigns(spec, steps, truth, wi, wo, anisotropic=True)
            continue
        if args.aniso and args.pilots:
            _aniso_pilots(measure, kin, theta_max, steps, truth, wi, wo)
            continue
        if args.aniso:
            _aniso(measure, kin, theta_max, steps, truth, wi, wo)
            continue
        if args.pilots:
            _pilots(measure, kin, theta_max, truth, wi, wo)
            continue
        variants = args.variants.split(",") if args.variants else ["both"]
        if args.campaigns:
            for variant in variants:
                with _variant(variant):
                    _campaigns(spec, steps, truth, wi, wo)
            continue
        if args.reach_time:
            _reach_time(spec, variants, args.reach_from_s, truth, wi, wo)
            continue
        if args.export:
            _exports(material, [int(b) for b in args.budgets.split(",")], wi, wo)
            continue
        print(f"  {'grid':>12} {'poses':>6} | {'uniform, gonio.brdf':>22} | {'uniform, same':>13} | "
              f"{'adaptive':>8} | {'lattice/adaptive':>16} {'same/adaptive':>13} | {'adaptive s':>10}")
        same_errors = {}
        for step in steps:
            uni = uniform_samples(step, kin, theta_max, measure)
            lat, cover = lattice_error(uni, step, truth, wi, wo)
            same = weighted_l1(LocalFit(uni).eval(wi, wo), truth, wi, wo)[0]
            same_errors[step] = (lat, same)
            t0 = time.perf_counter()
            ada, acq = adaptive_error(measure, kin, theta_max, len(uni), truth, wi, wo)
            took = time.perf_counter() - t0
            grid = f"iso:step={step:g}"
            print(f"  {grid:>12} {len(uni):>6} | {lat:>10.4f} ({cover:>5.1%} ans.) | {same:>13.4f} | "
                  f"{ada:>8.4f} | {lat / ada:>15.1f}x {same / ada:>12.1f}x | {took:>10.1f}", flush=True)
        if reach:
            uni5 = uniform_samples(5.0, kin, theta_max, measure)
            lat5, same5 = same_errors.get(5.0) or (lattice_error(uni5, 5.0, truth, wi, wo)[0],
                                                   weighted_l1(LocalFit(uni5).eval(wi, wo), truth, wi, wo)[0])
            _reach(measure, kin, theta_max, truth, wi, wo, len(uni5), lat5, same5, args.reach_from)


def _reach(measure, kin, theta_max, truth, wi, wo, n5, lat5, same5, start):
    """First budget (growing by 25 %) whose adaptive error is at or below each iso:step=5 error."""
    found = {}
    budget = start
    while len(found) < 2 and budget <= n5:
        err, _ = adaptive_error(measure, kin, theta_max, budget, truth, wi, wo)
        for name, target in (("gonio.brdf", lat5), ("same engine", same5)):
            if name not in found and err <= target:
                found[name] = (budget, err)
        budget = int(round(budget * 1.25))
    for name, target in (("gonio.brdf", lat5), ("same engine", same5)):
        if name in found:
            b, err = found[name]
            print(f"  to reach iso:step=5 ({n5} poses) through {name} ({target:.4f}): {b} adaptive poses "
                  f"({err:.4f}), {n5 / b:.1f}x fewer", flush=True)
        else:
            print(f"  to reach iso:step=5 through {name} ({target:.4f}): not within {n5} poses", flush=True)


def _aniso(measure, kin, theta_max, steps, truth, wi, wo):
    """The anisotropic row (module docstring)."""
    from gonio.brdf import MeasuredBRDF
    from gonio.dataset import SampledBRDF

    print(f"  {'grid':>12} {'poses':>6} | {'uniform, gonio.brdf':>30} | {'uniform, same':>13} | "
          f"{'adaptive':>8} | {'brdf/adaptive':>13} {'same/adaptive':>13} | {'adaptive s':>10}")
    for step in steps:
        ok, (ti, pi_, to, po) = reachable_pair(kin, *pair_lattice(step, theta_max), theta_max)
        ti, pi_, to, po = ti[ok], pi_[ok], to[ok], po[ok]
        uni = Samples(ti, to, po - pi_, measure(ti, to, po - pi_, phi_i=pi_), pi_)
        deg = [np.degrees(a) for a in (ti, pi_, to, po)]
        data = SampledBRDF(*deg, value=uni.value, stddev=np.zeros_like(uni.value),
                           attrs={"symmetries": {"reciprocity": True, "isotropy": False, "mirror": False},
                                  "grid": f"full:step={step:g}"})
        brdf = MeasuredBRDF(data)
        lat, cover = weighted_l1(brdf.eval(wi, wo).value, truth, wi, wo)
        same = weighted_l1(LocalFit(uni, domain="pair").eval(wi, wo), truth, wi, wo)[0]
        t0 = time.perf_counter()
        acq = acquire(measure, kin, theta_max, len(uni), anisotropic=True)
        ada = weighted_l1(LocalFit(acq.samples, domain="pair").eval(wi, wo), truth, wi, wo)[0]
        took = time.perf_counter() - t0
        grid = f"full:step={step:g}"
        label = f"{lat:.4f} ({brdf.method}, {cover:.1%} ans.)"
        print(f"  {grid:>12} {len(uni):>6} | {label:>30} | {same:>13.4f} | {ada:>8.4f} | "
              f"{lat / ada:>12.1f}x {same / ada:>12.1f}x | {took:>10.1f}", flush=True)


def _plane_pilot(kin, theta_max, share):
    """The specular plane swept over φi: θi, θo on ``m`` nodes from 0 to theta_max, φo = φi + 180°
    (forward scattering) or φi (backward), φi on ``k`` azimuths; the densest such set of at most ``share``
    reachable poses (m, k growing together)."""
    best = None
    for m in range(2, 40):
        k = max(2, 2 * (m - 1))
        t = np.linspace(0.0, theta_max, m)
        a, b, c, f = (x.ravel() for x in np.meshgrid(t, t, np.arange(k) * np.pi / k, [0.0, np.pi],
                                                     indexing="ij"))
        ok, angles = reachable_pair(kin, a, c, b, np.mod(c + f, 2 * np.pi), theta_max)
        if best is not None and ok.sum() > share:
            break
        best = tuple(x[ok] for x in angles)
    return best


def _aniso_pilots(measure, kin, theta_max, steps, truth, wi, wo):
    """The anisotropic pilot: the full:step=S grid (the default) against the specular plane swept over φi,
    at the adaptive budgets of ``steps``' pose counts."""
    print(f"  {'poses':>6} | {'pilot':>22} {'pilot poses':>11} | {'error':>7}")
    for step in steps:
        budget = int(reachable_pair(kin, *pair_lattice(step, theta_max), theta_max)[0].sum())
        for name, pilot in (("full grid (default)", None), ("specular plane x φi", _plane_pilot)):
            acq = acquire(measure, kin, theta_max, budget, anisotropic=True, pilot=pilot)
            err = weighted_l1(LocalFit(acq.samples, domain="pair").eval(wi, wo), truth, wi, wo)[0]
            print(f"  {budget:>6} | {name:>22} {acq.phases[0]:>11} | {err:>7.4f}", flush=True)


def _engines(measure, kin, theta_max, truth, wi, wo):
    uni = uniform_samples(10.0, kin, theta_max, measure)
    _, acq = adaptive_error(measure, kin, theta_max, len(uni), truth, wi, wo)
    print(f"  reconstruction variants, iso:step=10 ({len(uni)} poses) and adaptive at the same count")
    for domain in ("iso", "half"):
        for transform in ("linear", "log"):
            for degree in (1, 2):
                errs = [weighted_l1(LocalFit(s, domain, transform, degree).eval(wi, wo), truth, wi, wo)[0]
                        for s in (uni, acq.samples)]
                print(f"  {domain:>4} {transform:>6} degree {degree}: uniform {errs[0]:.4f}  "
                      f"adaptive {errs[1]:.4f}", flush=True)
    half_cells, _ = adaptive_error(measure, kin, theta_max, len(uni), truth, wi, wo, domain="half")
    print(f"  adaptive with cells in half/difference angles instead of (θi, θo, Δφ): {half_cells:.4f}",
          flush=True)


def _pilots(measure, kin, theta_max, truth, wi, wo):
    budget = len(uniform_samples(10.0, kin, theta_max, measure))
    print(f"  pilot fraction and round growth, {budget} poses")
    for fraction in (0.05, 0.1, 0.25, 0.5):
        for growth in (0.1, 0.2, 0.5):
            err, acq = adaptive_error(measure, kin, theta_max, budget, truth, wi, wo, pilot_fraction=fraction,
                                      growth=growth)
            print(f"  pilot {fraction:>4} ({acq.phases[0]:>4} poses), growth {growth}, "
                  f"{len(acq.phases) - 1:>3} rounds: {err:.4f}", flush=True)



def _measured_file(spec: str, grid: str) -> str:
    """``bsdf:FILE``: the bsdf export of a whole simulated ``grid`` campaign of ``spec``, in a temporary
    folder removed when the benchmark exits."""
    import atexit
    import shutil
    import tempfile

    from gonio.export import export

    tmp = tempfile.mkdtemp(prefix="bench-adaptive-measured-")
    atexit.register(shutil.rmtree, tmp, True)
    b, gantry_s, wall = _simulated(f"{tmp}/source", grid, spec)
    export(f"{tmp}/source", "bsdf", f"{tmp}/m.bsdf")
    print(f"measured material: {spec}, {grid} campaign ({b.n_samples} poses, gantry {gantry_s:.0f} s, "
          f"{wall:.0f} s wall), exported as bsdf ({os.path.getsize(f'{tmp}/m.bsdf'):,} bytes)", flush=True)
    return f"bsdf:{tmp}/m.bsdf"


def _simulated(folder, grid: str, spec: str):
    """``gonio simulate SPEC --grid GRID --out FOLDER`` in this process: (brdf, gantry s, wall s)."""
    from gonio.brdf import open_brdf
    from gonio.campaign import create_campaign
    from gonio.lifecycle import run_campaign
    from gonio.wiring import build_gantry

    cfg = load_config()
    t0 = time.perf_counter()
    c = create_campaign(folder, cfg, grid=grid, material=load(spec).spec)
    try:
        state, runner = run_campaign(c, build_gantry(cfg, spec))
        gantry_s = runner.campaign_s()
    finally:
        c.close()
    assert state == "done", state
    return open_brdf(folder), gantry_s, time.perf_counter() - t0


def _campaigns(spec, steps, truth, wi, wo, anisotropic=False):
    import tempfile

    uniform_kind, option = ("full", ",anisotropic=true") if anisotropic else ("iso", "")
    print(f"  {'grid':>26} {'poses':>6} {'gantry':>8} | {'error':>7} {'(answered)':>10} {'method':>9} | "
          f"{'uniform/this':>12} | {'wall s':>6}")
    with tempfile.TemporaryDirectory() as tmp:
        for step in steps:
            uniform = None
            runs = [f"{uniform_kind}:step={step:g}"]
            for k, grid in enumerate(runs):
                b, gantry_s, wall = _simulated(f"{tmp}/{step:g}-{k}", grid, spec)
                err, answered = weighted_l1(b.eval(wi, wo).value, truth, wi, wo)
                if uniform is None:
                    uniform = err
                    runs += [f"adaptive:poses={b.n_samples}{option}",
                             f"adaptive:budget_s={gantry_s:.0f}{option}"]
                print(f"  {grid:>26} {b.n_samples:>6} {gantry_s:>7.0f}s | {err:>7.4f} ({answered:>8.1%}) "
                      f"{b.method:>9} | {uniform / err:>11.1f}x | {wall:>6.1f}", flush=True)



@contextlib.contextmanager
def _variant(name):
    """New adaptive campaigns journal this variant's motion weight and checkpoint rule while the block
    runs (module docstring)."""
    from gonio.adaptive import plan

    kept = plan.MOTION_WEIGHT, plan.CHECKPOINTS_AS_NEEDED
    weight = kept[0] if name in ("motion", "both") else 0.0
    as_needed = name in ("checkpoints", "both")
    if name not in ("before", "motion", "checkpoints", "both"):
        raise SystemExit(f"--variants: {name!r} is not one of before, motion, checkpoints, both")
    plan.MOTION_WEIGHT, plan.CHECKPOINTS_AS_NEEDED = weight, as_needed
    print(f"  {name}: motion weight {weight:g}, checkpoints {'as needed' if as_needed else 'every round'}",
          flush=True)
    try:
        yield
    finally:
        plan.MOTION_WEIGHT, plan.CHECKPOINTS_AS_NEEDED = kept


def _reach_time(spec, variants, start_s, truth, wi, wo):
    """The --reach-time panel (module docstring)."""
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        b, uniform_s, _ = _simulated(f"{tmp}/iso5", "iso:step=5", spec)
        target = weighted_l1(b.eval(wi, wo).value, truth, wi, wo)[0]
        print(f"  iso:step=5: {b.n_samples} poses, gantry {uniform_s:.0f} s, error {target:.4f} (gonio.brdf)",
              flush=True)
        for variant in variants:
            with _variant(variant):
                budget, runs = start_s, []
                while budget <= uniform_s:
                    b, gantry_s, wall = _simulated(f"{tmp}/a{len(runs)}-{variant}",
                                                   f"adaptive:budget_s={budget:.0f}", spec)
                    err = weighted_l1(b.eval(wi, wo).value, truth, wi, wo)[0]
                    runs.append((gantry_s, err))
                    print(f"    budget_s={budget:>6.0f}: {b.n_samples:>5} poses, gantry {gantry_s:>6.0f} s, "
                          f"error {err:.4f} ({wall:.0f} s wall)", flush=True)
                    if err <= target:
                        break
                    budget *= 1.25
                if runs[-1][1] > target:
                    print(f"    not within {uniform_s:.0f} s of gantry time", flush=True)
                    continue
                (t0, e0), (t1, e1) = runs[-2] if len(runs) > 1 else runs[-1], runs[-1]
                slope = (np.log(t1) - np.log(t0)) / (np.log(e1) - np.log(e0)) if e0 != e1 else 0.0
                reach = float(np.exp(np.log(t0) + (np.log(target) - np.log(e0)) * slope)) if t0 != t1 else t1
                print(f"    gantry time to the iso:step=5 error: {reach:.0f} s (interpolated), "
                      f"{uniform_s / reach:.1f}x less than iso:step=5", flush=True)


def _exports(material, budgets, wi, wo):
    """The --export panel (module docstring)."""
    import tempfile

    import drjit as dr
    import mitsuba as mi

    from gonio.dataset import read_brdf
    from gonio.export import export
    from gonio.formats.rgl import build_measured, estimate_ndf, retro_from_samples
    from gonio.formats.tensor import read_tensor, write_tensor
    from gonio.geometry import sph_to_vec

    mi.set_variant("llvm_ad_rgb")
    v = material.values()
    alpha = v["alpha_u"]
    rough = mi.load_dict({"type": "roughconductor", "distribution": "ggx", "alpha": alpha,
                          "eta": {"type": "rgb", "value": list(v["eta"])},
                          "k": {"type": "rgb", "value": list(v["k"])}})

    def mitsuba(bsdf):
        si = dr.zeros(mi.SurfaceInteraction3f, len(wi))
        si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
        si.wi = mi.Vector3f(*wi.astype(np.float32).T)
        return np.array(bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(*wo.astype(np.float32).T)))

    reference = mitsuba(rough)
    shape = (48, 48)
    ux, uy = np.meshgrid(np.linspace(0, 1, shape[1]), np.linspace(0, 1, shape[0]))
    theta_m = ux ** 2 * np.pi / 2

    def ndf_error(ndf):
        """Against GGX α: Σ |D̂ − D| cos θm dm / Σ D cos θm dm over the table's nodes (dm ∝ u_x sin θm)."""
        c = np.cos(theta_m)
        weight = c * ux * np.sin(theta_m)
        truth = alpha ** 2 / (np.pi * (c * c * (alpha ** 2 - 1) + 1) ** 2)
        return float((np.abs(ndf - truth) * weight).sum() / (truth * weight).sum())

    def file_error(path):
        return float(np.abs(mitsuba(mi.load_dict({"type": "measured", "filename": str(path)}))
                            - reference).sum() / reference.sum())

    print(f"  Mitsuba roughconductor α={alpha:g}, η={v['eta']}, k={v['k']} ({len(wi):,} pairs)")
    print(f"  {'grid':>22} {'poses':>6} {'gantry':>8} | {'file vs roughconductor':>22} | "
          f"{'file NDF vs GGX':>15} | {'export s':>8}")
    with tempfile.TemporaryDirectory() as tmp:
        for grid in ["iso:step=5"] + [f"adaptive:poses={b}" for b in budgets]:
            folder = f"{tmp}/{grid.replace(':', '-').replace('=', '')}"
            b, gantry_s, _ = _simulated(folder, grid, material.spec)
            t0 = time.perf_counter()
            export(folder, "bsdf", f"{folder}/m.bsdf")
            took = time.perf_counter() - t0
            ndf = read_tensor(f"{folder}/m.bsdf")["ndf"].astype(np.float64)
            err = file_error(f"{folder}/m.bsdf")
            print(f"  {grid:>22} {b.n_samples:>6} {gantry_s:>7.0f}s | {err:>22.4f} | "
                  f"{ndf_error(ndf):>15.4f} | {took:>8.2f}", flush=True)
            if not grid.startswith("adaptive"):
                continue
            data = read_brdf(f"{folder}/brdf.h5")
            swi = sph_to_vec(np.radians(data.theta_i), np.radians(data.phi_i))
            swo = sph_to_vec(np.radians(data.theta_o), np.radians(data.phi_o))

            def values(a, c, b=b):
                return b.eval(a, c).value

            retros = {f"samples θd <= {t}°": retro_from_samples(swi, swo, data.value, t)
                      for t in (5, 10, 20, 30)}
            retros["reconstruction f(ω, ω)"] = lambda w, values=values: values(w, w) @ LUMA
            retros["exact (the material)"] = lambda w: material.eval(w, w) @ LUMA
            for name, retro in retros.items():
                if retro is None:
                    print(f"      NDF from {name:<24}: too few samples")
                    continue
                fields, _ = build_measured(values, theta_i_deg=np.linspace(0, 80, 17), theta_max_deg=80.0,
                                           retro_fr=lambda w, r=retro: np.repeat(r(w)[:, None], 3, axis=1))
                path = f"{folder}/variant.bsdf"
                write_tensor(path, fields)
                nd = estimate_ndf(retro, shape)[0]
                print(f"      NDF from {name:<24}: NDF vs GGX {ndf_error(nd):.4f}, file vs roughconductor "
                      f"{file_error(path):.4f}", flush=True)
            fields, _ = build_measured(values, theta_i_deg=np.linspace(0, 80, 17),
                                       retro_fr=lambda w, r=retros["reconstruction f(ω, ω)"]:
                                       np.repeat(r(w)[:, None], 3, axis=1))
            write_tensor(f"{folder}/before.bsdf", fields)
            print(f"      before (zeros past 80°, NDF through the reconstruction): file vs roughconductor "
                  f"{file_error(f'{folder}/before.bsdf'):.4f}", flush=True)


if __name__ == "__main__":
    main()
