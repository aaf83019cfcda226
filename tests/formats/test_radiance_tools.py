"""Radiance's own tools read our PAB-Opto export: pabopto2bsdf -> bsdf2klems -> checkBSDF.

The material is a Lambertian of albedo 0.6, whose answers are exact: hemispherical reflectance 0.6 at
every incidence, and f_r(ωi, ωo) = f_r(ωo, ωi). A second data set multiplies it by g(θi) = 0.6 + 0.8 cos θi,
which breaks reciprocity by a known amount. checkBSDF's energy and reciprocity figures are held against
these; the reciprocal control measures what Radiance's own resampling (its radial-basis interpolant and the
Klems patches) adds, and that is the tolerance of the non-reciprocal comparison.
"""

import json
import re
import subprocess
import sys

import numpy as np
import pytest
from brdf_samples import sampled

from gonio.dataset import SampledBRDF
from gonio.export import export
from gonio.formats.radiance import read_pabopto

pyradiance = pytest.importorskip("pyradiance")
from pyradiance.anci import BINPATH  # noqa: E402

ALBEDO = 0.6


def _g(theta_deg):
    return 0.6 + 0.8 * np.cos(np.radians(theta_deg))


def _check_bsdf(xml) -> dict:
    """checkBSDF's table for the reflecting side: Lambertian Y %, max directional-hemispherical %, the
    smallest patch (deg), reciprocity error min/avg/max %."""
    run = subprocess.run([str(BINPATH / "checkBSDF"), str(xml)], capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stderr
    energy, recip = run.stdout.split("Reciprocity Error")
    rows = {m.group(1): m.group(2).split() for m in re.finditer(r"^(\w+ Refl)\s+(.*)$", energy, re.M)}
    rrows = {m.group(1): m.group(2).split() for m in re.finditer(r"^(\w+ Refl)\s+(.*)$", recip, re.M)}
    lit = [k for k, v in rows.items() if float(v[1]) > 0]
    assert len(lit) == 1, run.stdout  # one reflecting side, no transmission
    assert all(float(x) == 0 for k, v in rrows.items() if k != lit[0] for x in v)
    v, r = rows[lit[0]], rrows[lit[0]]
    return {"lambertian_y": float(v[1]) / 100, "max_hemi": float(v[3].rstrip("%")) / 100,
            "min_angle_deg": float(v[4]), "recip": tuple(float(x) for x in r), "text": run.stdout}


_HEMI = """
import json, sys
from pyradiance import bsdf
sd = bsdf.load_file(sys.argv[1])
print(json.dumps([bsdf.direct_hemi(sd, float(t), 0.0, bsdf.SAMPLE_ALL) for t in sys.argv[2:]]))
"""


def _hemispherical(xml, thetas_deg) -> list[float]:
    """Radiance's directional-hemispherical reflectance at incidence θ (φ = 0), from its BSDF library.

    Asked in a child process: the library (pyradiance's compiled ``bsdf``) crashed the whole test
    process with a segmentation fault in ``load_file``/``direct_hemi`` about one run in ten of the
    suite, never when run alone. A child that dies of a signal is asked again, at most twice more; any
    other failure, and a third crash, fails the test."""
    argv = [sys.executable, "-c", _HEMI, str(xml), *(str(float(t)) for t in thetas_deg)]
    for _ in range(3):
        run = subprocess.run(argv, capture_output=True, text=True, timeout=120)
        if run.returncode >= 0:
            break
    assert run.returncode == 0, (run.returncode, run.stderr)
    return json.loads(run.stdout)


def _klems_centres_deg(xml) -> np.ndarray:
    """θ of every Klems patch centre, read from the basis the XML file declares."""
    text = xml.read_text()
    block = text.split("<AngleBasis>")[1].split("</AngleBasis>")[0]
    theta = [float(t) for t in re.findall(r"<Theta>([^<]+)</Theta>", block)]
    nphi = [int(n) for n in re.findall(r"<nPhis>([^<]+)</nPhis>", block)]
    return np.repeat(theta, nphi)


def _to_radiance(data, folder):
    """Our export, then Radiance: the interpolant (.sir), the Klems quarter-basis XML, its checkBSDF."""
    export(data, "radiance", folder / "pab", theta_step_deg=10.0)
    files = sorted(str(p) for p in (folder / "pab").glob("*.pabopto.dat"))
    sir = folder / "m.sir"
    sir.write_bytes(pyradiance.pabopto2bsdf(*files, symmetry="isotropic"))
    assert sir.read_bytes().startswith(b"#?RADIANCE")
    xml = folder / "m.xml"
    xml.write_bytes(pyradiance.bsdf2klems(str(sir), spp=64, quater=True))
    return files, xml


@pytest.fixture(scope="module")
def lambert(tmp_path_factory):
    folder = tmp_path_factory.mktemp("lambert")
    data = sampled(f"lambert:albedo={ALBEDO}", "iso:step=10,reciprocity=false")
    files, xml = _to_radiance(data, folder)
    return data, files, xml, _check_bsdf(xml)


def test_our_files_hold_the_albedo_exactly(lambert):
    _, files, _, _ = lambert
    for f in files:
        np.testing.assert_allclose(read_pabopto(f)["value"], ALBEDO / np.pi, rtol=1e-9)


def test_checkbsdf_energy_matches_the_albedo(lambert):
    _, _, xml, fig = lambert
    print(fig["text"])
    # Radiance's interpolant of a constant overshoots by ~3 % (61.9 % max here); a BRDF written with the
    # cosine (a DSF) would read 0.4, one off by π 0.19 or 1.9: 4 % tells them all apart.
    assert fig["lambertian_y"] == pytest.approx(ALBEDO, rel=0.01)
    assert fig["max_hemi"] == pytest.approx(ALBEDO, rel=0.04)
    hemi = _hemispherical(xml, (0, 20, 40, 60, 80))
    np.testing.assert_allclose(hemi, ALBEDO, rtol=0.04)


def test_checkbsdf_reciprocity_reads_the_datas_reciprocity(lambert, tmp_path):
    data, _, _, fig = lambert
    floor = fig["recip"][1]  # avg error % on exactly reciprocal data: Radiance's resampling alone
    assert floor < 5.0
    scaled = data.value * _g(data.theta_i)[:, None]
    broken = SampledBRDF(data.theta_i, data.phi_i, data.theta_o, data.phi_o, scaled, 0.01 * scaled,
                         attrs=data.attrs)
    _, xml = _to_radiance(broken, tmp_path)
    nr = _check_bsdf(xml)
    print(nr["text"])
    # checkBSDF compares each matrix entry with the reversed query at patch centres: on these data the
    # relative error of a pair is |1 - g(θa)/g(θb)|, averaged over every ordered pair of patches.
    g = _g(_klems_centres_deg(xml))
    expected = 100 * np.abs(1 - g[:, None] / g[None, :]).mean()
    assert nr["recip"][1] == pytest.approx(expected, abs=floor)
    assert nr["recip"][1] > 4 * floor
    # Radiance sees the incidence where we wrote it: reflectance falls with θi as g does (swapped
    # directions would make it flat; reciprocity averaging in the interpolant keeps the ratio >= 1.35).
    h0, h80 = _hemispherical(xml, (0, 80))
    assert h0 / h80 > 1.3
