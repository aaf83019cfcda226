"""gonio plot: every kind renders a readable PNG, and EXR pixels hold gonio.brdf at their directions."""

import numpy as np
import pytest
from brdf_samples import sampled
from built_once import built_once

from gonio.brdf import Reason, open_brdf
from gonio.cli import main
from gonio.geometry import from_half_diff
from gonio.plot import plot
from gonio.registries import PLOT_KINDS

SPEC = "ggx:alpha=0.15,metal=copper,rho_d=0.2,rho_s=0.8"


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    from gonio.campaign import create_campaign
    from gonio.config import load_config
    from gonio.lifecycle import run_campaign
    from gonio.wiring import build_gantry

    def build(parent):
        folder = parent / "copper"
        # raster order: the plots do not depend on the order, and the tour takes 0.45 s longer to plan
        c = create_campaign(folder, load_config(), grid="iso:step=15,reciprocity=false,order=raster",
                            material=SPEC, seed=2)
        try:
            run_campaign(c, build_gantry(c.cfg, SPEC, seed=2))
        finally:
            c.close()
        return folder

    return built_once(tmp_path_factory, "plot-copper", build)  # the tests only read it


def _exr(path):
    oiio = pytest.importorskip("OpenImageIO")
    inp = oiio.ImageInput.open(str(path))
    try:
        spec = inp.spec()
        pixels = inp.read_image("float")
        header = {a.name: a.value for a in spec.extra_attribs}
        return np.asarray(pixels, dtype=np.float64), spec.channelnames, header
    finally:
        inp.close()


def _centres(n):
    return (np.arange(n) + 0.5) / n


@pytest.mark.parametrize("kind", PLOT_KINDS.names())
def test_every_kind_renders_a_png_that_is_not_blank(campaign, tmp_path, kind, capsys):
    from matplotlib.image import imread

    out = tmp_path / f"{kind}.png"
    assert main(["plot", str(campaign), "--kind", kind, "--out", str(out)]) == 0
    assert str(out) in capsys.readouterr().out
    img = imread(out)[..., :3]
    assert img.shape[0] > 300 and img.shape[1] > 400
    assert img.var() > 0.01  # not blank
    assert np.mean(img.sum(axis=2) < 2.9) > 0.05  # a real share of the pixels is drawn, not background


def test_pdf_and_bad_requests(campaign, tmp_path, capsys):
    assert main(["plot", str(campaign), "--kind", "merl", "--out", str(tmp_path / "m.pdf")]) == 0
    assert (tmp_path / "m.pdf").read_bytes().startswith(b"%PDF")
    for argv, words in ((["--kind", "cubes", "--out", "x.png"], "--kind: 'cubes' is unknown"),
                        (["--kind", "polar", "--out", "x.jpg"], "--out: x.jpg must end in"),
                        (["--kind", "hemisphere", "--theta-i", "95", "--out", "x.png"],
                         "--theta-i: must be")):
        assert main(["plot", str(campaign), *argv]) == 2
        err = capsys.readouterr().err.strip()
        assert words in err and "\n" not in err
    with pytest.raises(ValueError, match="used the reciprocity shortcut"):
        plot(sampled(SPEC, "iso:step=30"), "reciprocity", tmp_path / "r.png")
    assert not list(tmp_path.glob("*.png")) and not list(tmp_path.glob(".*"))


def test_exr_pixels_are_the_brdf_at_their_directions(campaign, tmp_path):
    b = open_brdf(campaign)
    for kind in ("polar", "hemisphere", "merl", "reciprocity"):
        out = tmp_path / f"{kind}.exr"
        assert main(["plot", str(campaign), "--kind", kind, "--theta-i", "45", "--phi-i", "20",
                     "--out", str(out)]) == 0
        got, channels, header = _exr(out)
        assert tuple(channels) == ("R", "G", "B") and header["gonio:kind"] == kind
        assert float(header["gonio:blocked_cone_deg"]) == 5.0  # the sim gantry's clearance: NaN there
        h, w, _ = got.shape
        u, v = np.meshgrid(_centres(w), _centres(h))
        if kind == "polar":
            rows = np.array(eval(header["gonio:rows_deg"]))  # noqa: S307 - our own repr of a list
            so = -90.0 + 180.0 * u
            want = b.eval_deg(rows[:, None] + 0 * so, 20.0, np.abs(so), np.where(so >= 0, 200.0, 20.0)).value
        elif kind == "hemisphere":
            x, y = 2 * u - 1, 1 - 2 * v
            r = np.hypot(x, y)
            want = b.eval_deg(45.0, 20.0, np.where(r < 1, 90 * r, np.nan), np.degrees(np.arctan2(y, x))).value
        elif kind == "merl":
            wi, wo = from_half_diff(np.radians(90 * u).ravel(), 0.0, np.radians(90 * (1 - v)).ravel(),
                                    np.radians(90.0))
            want = b.eval(wi, wo).value
        else:
            top = float(header["gonio:theta_max_deg"])
            ti, to = top * u, top * (1 - v)
            f = b.eval_deg(ti, 20.0, to, 200.0).value
            g = b.eval_deg(to, 200.0, ti, 20.0).value
            want = (f - g) / (0.5 * (f + g))
            want[(ti > to).ravel()] = np.nan
        want = want.reshape(got.shape)
        np.testing.assert_array_equal(np.isnan(got), np.isnan(want), err_msg=kind)
        ok = ~np.isnan(want)
        assert ok.mean() > 0.3, kind
        np.testing.assert_allclose(got[ok], want[ok], rtol=2e-6, atol=1e-6 if kind == "reciprocity" else 0,
                                   err_msg=kind)


def test_albedo_exr_is_the_cosine_weighted_integral_and_a_lambertian_stays_below_one(tmp_path):
    data = sampled("lambert:albedo=0.6", "iso:step=10", theta_max_deg=80.0)
    plot(data, "albedo", tmp_path / "a.exr")
    got, _, header = _exr(tmp_path / "a.exr")
    cols = np.array(eval(header["gonio:cols_deg"]))  # noqa: S307 - our own repr of a list
    b = open_brdf(data)
    t, p = np.meshgrid(np.arange(0.5, 90, 1.0), np.arange(2.5, 360, 5.0), indexing="ij")
    w = np.cos(np.radians(t)) * np.sin(np.radians(t)) * np.radians(1.0) * np.radians(5.0)
    for k, ti in enumerate(cols):
        ev = b.eval_deg(ti, 0.0, t.ravel(), p.ravel())
        ok = ev.reason == Reason.OK
        np.testing.assert_allclose(got[0, k], (w.ravel()[ok, None] * ev.value[ok]).sum(0), rtol=1e-6)
    # θo up to 80° holds sin²(80°) = 97 % of the projected solid angle: 0.6 * 0.97
    np.testing.assert_allclose(got[0, :, 1], 0.6 * np.sin(np.radians(80.0)) ** 2, rtol=0.01)


def test_the_reciprocity_plot_counts_each_measured_pair_once(campaign, tmp_path):
    """It counted every sample against the interpolant at its swap: 603 'pairs' where the report's
    check (and this independent count) finds 299 pairs measured both ways."""
    import re

    from gonio.dataset import read_brdf

    rep = plot(campaign, "reciprocity", tmp_path / "r.png")
    data = read_brdf(campaign / "brdf.h5")
    ti, pi_, to, po = np.round(np.asarray(data.planned, float), 2).T
    dphi = np.where((ti == 0) | (to == 0), 0.0, np.mod(po - pi_, 360.0))
    keys = set(zip(ti, to, dphi, strict=True))
    partner = {k: (k[1], k[0], round((360.0 - k[2]) % 360.0, 2)) for k in keys}
    both = {frozenset((k, partner[k])) for k in keys if partner[k] in keys and partner[k] != k}
    assert 250 < len(both) < len(data.value) / 2
    (note,) = [n for n in rep.notes if "measured pairs" in n]
    count, beyond3 = re.match(r"(\d+) measured pairs, each counted once; ([\d.]+) %", note).groups()
    assert note.endswith(" % by more than 2 sigma")   # it ended "by more than 2", the unit missing
    assert int(count) == len(both)
    from gonio.brdf import open_brdf
    from gonio.report.checks import reciprocity_pairs

    assert float(beyond3) == round(100 * reciprocity_pairs(data, open_brdf(data))["beyond_3"], 1)


def test_titles_break_between_items_never_inside_a_value():
    from gonio.plot import _title

    b = open_brdf(sampled(SPEC, "iso:step=30"))
    lines = _title("copper", b, width=30).splitlines()
    spec, grid = b.attrs["material"], b.attrs["grid"].split(",order=")[0]
    assert len(lines) > 3 and "".join(lines[1:]) == spec + grid
    ends = (spec, grid)
    # a line ends after a comma or where the spec or the grid ends: never inside a key=value
    assert all(line.endswith(",") or any(e.endswith(line) for e in ends) for line in lines[1:]), lines


def _true_albedo(spec, theta_i_deg):
    """∫ f_r cos θo dωo of the material itself (midpoint rule, 0.2° × 1°)."""
    from gonio.geometry import sph_to_vec
    from gonio.sim.materials import load

    t, p = np.meshgrid(np.radians(np.arange(0.1, 90, 0.2)), np.radians(np.arange(0.5, 360, 1.0)),
                       indexing="ij")
    wo = sph_to_vec(t.ravel(), p.ravel())
    w = (np.cos(t) * np.sin(t)).ravel() * np.radians(0.2) * np.radians(1.0)
    wi = np.ascontiguousarray(np.broadcast_to(sph_to_vec(np.radians(theta_i_deg), 0.0), wo.shape))
    return (w[:, None] * load(spec).eval(wi, wo)).sum(axis=0)


def test_the_albedo_plot_reads_a_lambertian_right_and_says_where_the_peak_went_unmeasured(campaign, tmp_path):
    """A Lambertian 0.5 read 0.47 (only the measured part of the hemisphere, without saying so on the
    curve), and the copper's albedo fell below θi = 15° with nothing on the figure saying why."""
    from gonio.campaign import create_campaign
    from gonio.config import load_config
    from gonio.lifecycle import run_campaign
    from gonio.wiring import build_gantry

    folder = tmp_path / "lambert"
    c = create_campaign(folder, load_config(), grid="iso:step=15,order=raster",  # the tour: 0.3 s more
                        material="lambert:albedo=0.5", seed=3)
    try:
        run_campaign(c, build_gantry(c.cfg, "lambert:albedo=0.5", seed=3))
    finally:
        c.close()
    rep = plot(folder, "albedo", tmp_path / "lambert.png")
    assert rep.slice.image.min() < 0.47           # the measured part alone: the gaps are real
    np.testing.assert_allclose(rep.shown["hemisphere"], 0.5, rtol=0.01)

    rep = plot(campaign, "albedo", tmp_path / "copper.png")
    th = np.round(np.asarray(rep.slice.attrs["cols_deg"]), 6)
    gap = rep.shown["peak_unmeasured"]
    # the mirror pose of θi = 0 is retro-reflection (never measured); those of the lattice's θi = 15°, 30°
    # were measured
    assert gap[th == 0].all() and not gap[(th == 15) | (th == 30)].any()
    assert any("occlusion gap" in n and n.startswith("θi 0–") for n in rep.notes)
    whole, lower = rep.shown["hemisphere"], rep.slice.image[0]
    for t in (15.0, 30.0, 45.0):
        k = int(np.flatnonzero(th == t)[0])
        truth = _true_albedo(SPEC, t)
        assert np.all(whole[k] >= lower[k]) and np.all(whole[k] <= truth * 1.03), (t, whole[k], truth)
        assert np.all(np.abs(whole[k] - truth) < np.abs(lower[k] - truth) + 1e-9)   # closer than the bound


def test_the_log_polar_panel_keeps_the_diffuse_body_out_of_its_centre(campaign, tmp_path):
    """Its centre sat just below the least value, so a copper's diffuse body (0.07 sr⁻¹ beside a 30 sr⁻¹
    peak) was drawn within 5 % of the radius from the centre."""
    rep = plot(campaign, "polar", tmp_path / "p.png")
    lo, hi = rep.shown["polar_rlim"]
    out_from_centre = np.log10(rep.shown["least"] / lo) / np.log10(hi / lo)
    assert out_from_centre >= 0.2, out_from_centre


def test_one_pass_layout_keeps_every_label_legend_and_title_inside_and_apart():
    """gonio.figure_layout.lay_out (the report's and these plots' layout): on a grid with long axis
    labels, a legend placed beside its axes, a title over every panel and a colour-bar column, every
    axes' labels lie inside the figure, clear of the title and of each other's."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from gonio.figure_layout import inside, lay_out

    fig = Figure(figsize=(8.0, 6.0), dpi=100)
    title = fig.text(0.5, 0.99, "a title\nover every panel", ha="center", va="top", fontsize=12)
    grid = fig.add_gridspec(2, 3, width_ratios=[1.0, 1.6, 0.06])
    axes = [fig.add_subplot(grid[i, j]) for i in range(2) for j in range(2)]
    for k, ax in enumerate(axes):
        ax.plot([0, 1e5], [0, 1e5], label=f"a long legend entry {k}")
        ax.set_ylabel("a long\ny label (units)")
        ax.set_xlabel("an x label")
        ax.set_title(f"panel {k}")
    axes[1].legend(loc="upper left", bbox_to_anchor=(1.01, 1.0))
    bar = fig.add_subplot(grid[:, 2])
    fig.colorbar(axes[0].scatter([0, 1], [0, 1], c=[0, 1]), cax=bar, label="colour (units)")
    lay_out(fig)
    renderer = FigureCanvasAgg(fig).get_renderer()
    boxes = [ax.get_tightbbox(renderer) for ax in [*axes, bar]]
    edge = fig.bbox
    for box in boxes:
        assert edge.x0 <= box.x0 and box.x1 <= edge.x1 and edge.y0 <= box.y0 and box.y1 <= edge.y1, box
    top = title.get_window_extent(renderer)
    for k, box in enumerate(boxes):
        assert not box.overlaps(top), k
        for j, other in enumerate(boxes[:k]):
            assert not box.overlaps(other), (j, k)
    # a title wider than the figure cannot be laid out: inside() says so (gonio plot then crops to it)
    assert inside(fig)
    axes[0].set_title("a title far wider than its panel and than the whole figure " * 3)
    assert not inside(fig)



def _gold_foil(sd_deg=0.4, seed=5):
    """A gold foil (ggx α = 0.05: a 300 sr⁻¹ peak over a body near 1e-3 sr⁻¹) on iso:step=15 as a gantry
    of the sim design measures it: no pose within its 5° clearance of retro-reflection (the config
    snapshot records the design, the clearance its default), and read-back directions that scatter about
    the plan by ``sd_deg``, farther than the plan tolerance: gonio.brdf places the samples at them and
    interpolates with its scattered engine, which reaches across the blocked cone."""
    from gonio.dataset import SampledBRDF

    data = sampled("ggx:alpha=0.05,metal=gold", "iso:step=15", theta_max_deg=80.0)
    plan = np.stack([data.theta_i, data.phi_i, data.theta_o, data.phi_o], axis=1)
    ti, pi_, to, po = np.radians(plan).T
    cos = np.cos(ti) * np.cos(to) + np.sin(ti) * np.sin(to) * np.cos(po - pi_)
    keep = cos < np.cos(np.radians(5.0))
    plan = plan[keep]
    read = plan + np.random.default_rng(seed).normal(0.0, sd_deg, plan.shape)
    read[:, [0, 2]] = np.abs(read[:, [0, 2]])
    out = SampledBRDF(*read.T, data.value[keep], data.stddev[keep], planned=plan,
                      attrs={**data.attrs, "config": {"kinematics": {"design": "two-arm"}}})
    assert open_brdf(out).method == "scattered"
    return out


def test_polar_lines_join_neighbouring_samples_and_never_cross_the_blocked_cone(tmp_path):
    """On a real gantry's read-back angles the polar plot drew the scattered interpolant straight across
    the retro-reflection gap (θo = θi on the light side, where the light arm hides the detector): a line
    through 15° of signed θo on each side of a direction never measured, as if a valley had been seen.
    And the foil's light side (f_r near 1e-3 beside a 300 sr⁻¹ peak) lay below both panels' floor, set
    from the 0.5th percentile of all values: those measured points were not drawn at all."""
    data = _gold_foil()
    rep = plot(data, "polar", tmp_path / "p.png")
    rows = rep.slice.attrs["rows_deg"]
    signed = -90.0 + 180.0 * _centres(rep.slice.image.shape[1])
    for k, t in enumerate(rows):  # the slice (and so an EXR) holds nothing inside the blocked cone
        assert np.isnan(rep.slice.image[k][np.abs(signed + t) < 5.0]).all(), t
    from gonio.slices import blocked_cone_deg

    assert blocked_cone_deg(open_brdf(data)) == 5.0  # the design's default clearance, from the config
    step = rep.shown["polar_step"]
    assert step == 15.0 and len(rows) >= 4
    plan = np.round(np.asarray(data.planned, float), 6)
    dphi = np.mod(plan[:, 3] - plan[:, 1], 360.0)
    y = np.asarray(data.value) @ np.array([0.2126, 0.7152, 0.0722])
    # each sample and its reciprocal (the campaign's shortcut): planned θi, θo, and the read-back θo
    members = ((plan[:, 0], plan[:, 2], np.asarray(data.theta_o, float)),
               (plan[:, 2], plan[:, 0], np.asarray(data.theta_i, float)))
    least = np.inf
    for k, t in enumerate(rows):
        # this θi's samples in the plane of incidence (by their plan), at their read-back signed θo
        xs = []
        for ti, to, at in members:
            mine = (ti == t) & (np.isin(dphi, (0.0, 180.0)) | (to == 0))
            least = min(least, y[mine].min(initial=np.inf))
            xs += [np.where(dphi[mine] == 180.0, 1.0, -1.0) * at[mine]]
        xs = np.concatenate(xs)
        xs = np.sort(np.concatenate([xs, -xs]) if t == 0 else xs)  # ωi at the pole: in every plane
        runs = rep.shown["polar_lines"][k]
        assert runs, t
        for x, v in runs:
            assert np.isfinite(v).all() and np.all(np.diff(x) > 0)
            # a run starts and ends at measured samples, and the samples it passes are one step apart
            assert np.abs(xs - x[0]).min() < 1e-9 and np.abs(xs - x[-1]).min() < 1e-9, (t, x[0], x[-1])
            inside = xs[(xs >= x[0]) & (xs <= x[-1])]
            assert np.diff(inside).max() <= step + 2.0, (t, inside)
            assert not (x[0] < -t < x[-1]), (t, x[0], x[-1])  # no line over the retro-reflection direction
        if t > 0:  # the gap there is hatched as not measured
            assert any(lo <= -t <= hi for lo, hi in rep.shown["polar_unmeasured"][k]), t
    # every measured point of the rows drawn lies on both panels' axes
    assert 0 < least < 0.01 and rep.shown["polar_rlim"][0] <= least and rep.shown["polar_ylim"][0] <= least


def test_the_hemisphere_leaves_the_blocked_cone_blank(tmp_path):
    """The scattered engine filled the cone about ωi where the light arm hides the detector: the image
    showed a smooth f_r under the light's own marker, which no gantry of this design can measure."""
    rep = plot(_gold_foil(), "hemisphere", tmp_path / "h.png", theta_i_deg=45.0)
    n = rep.slice.image.shape[0]
    x, y = np.meshgrid(2 * _centres(n) - 1, 1 - 2 * _centres(n))
    to, po = np.radians(90 * np.hypot(x, y)), np.arctan2(y, x)
    ti = np.radians(45.0)
    cos = np.cos(ti) * np.cos(to) + np.sin(ti) * np.sin(to) * np.cos(po)
    sep = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))  # degrees from ωi (φi = 0)
    assert (sep < 5.0).sum() > 20 and np.isnan(rep.slice.image[sep < 4.9]).all()
    assert np.isfinite(rep.slice.image[(sep > 8.0) & (sep < 12.0)]).mean() > 0.9  # blank only where blocked
