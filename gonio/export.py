"""Exports of a measured BRDF to the files renderers and tools read.

``export(source, fmt, out)`` takes a campaign folder, a ``brdf.h5``, a SampledBRDF or an open
:class:`~gonio.brdf.MeasuredBRDF`, writes ``out`` (atomically; a folder for ``radiance``) and returns an
:class:`ExportReport`: how many cells came from the data as measured, how many were interpolated through
:mod:`gonio.brdf`, how many are empty (no support: below the horizon, beyond the measured range, gaps).

The formats are the registry :data:`gonio.registries.EXPORT_FORMATS`: each entry's target is a function
``write(job, out) -> ExportReport`` of an :class:`ExportJob` (the data, opened as the format needs it);
a plugin adds a format with one module (docs/EXTENDING.md). The built-in ones:

======================  =====================================================================================
format                  what is written
======================  =====================================================================================
``merl``                MERL ``.binary`` (f_r; empty cells −1, MERL's "no data"). A ``merl:stride=1``
                        campaign fills its cells exactly; other campaigns are resampled at bin centres.
``bsdf``                Mitsuba 3 / pbrt-v4 measured-BSDF tensor file, RGB (:mod:`gonio.formats.rgl`). The
                        format has no "no data": cells in gaps of a lattice campaign (unmeasured poses such
                        as retro-reflection) take the scattered engine's value where it supports them.
``bsdf-spectral``       The same with ``spectra`` and ``wavelengths`` (360–830 nm every 10 nm) from R, G, B by
                        a fixed linear basis (:func:`gonio.formats.rgl.rgb_to_spectrum`).
``radiance``            A folder of PAB-Opto files, one per incidence (CIE-Y), for ``pabopto2bsdf``.
``csv``                 The measured samples, one row each (no interpolation).
``h5``                  The sampled dataset itself (``brdf.h5`` layout).
======================  =====================================================================================
"""

from __future__ import annotations

import json
import os
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gonio import software_version
from gonio.brdf import MeasuredBRDF, Reason, open_brdf
from gonio.dataset import BRDF_NAME, SampledBRDF, read_brdf, write_brdf
from gonio.formats import atomic_path
from gonio.formats.csv import write_csv
from gonio.formats.merl import MERL_BINS, write_merl
from gonio.formats.radiance import LUMINANCE_WEIGHTS, write_pabopto
from gonio.formats.rgl import NEAR_RETRO_DEG, build_measured, retro_from_samples
from gonio.formats.tensor import write_tensor
from gonio.geometry import merl_centre_angles, sph_to_vec
from gonio.registries import EXPORT_FORMATS

__all__ = ["export", "ExportReport", "ExportJob", "parse_formats", "export_merl", "export_bsdf",
           "export_bsdf_spectral", "export_radiance", "export_csv", "export_h5", "tally", "SPECTRAL_NM"]

#: Wavelengths of ``bsdf-spectral`` files, nm.
SPECTRAL_NM = tuple(float(x) for x in range(360, 831, 10))


@dataclass
class ExportReport:
    """What an export wrote.

    Attributes
    ----------
    format : str
    paths : list of Path
        Files written.
    cells : int
        Cells (values) the format holds.
    from_data, interpolated, empty : int
        Cells filled by a measured sample as it is, by interpolation, and left without data.
    seconds : float
        Wall time of the export.
    notes : list of str
        Conventions of the file (units, cosine) and anything worth knowing.
    """

    format: str
    paths: list = field(default_factory=list)
    cells: int = 0
    from_data: int = 0
    interpolated: int = 0
    empty: int = 0
    seconds: float = 0.0
    notes: list = field(default_factory=list)

    def __str__(self) -> str:
        where = str(self.paths[0]) + (f" (+{len(self.paths) - 1} files)" if len(self.paths) > 1 else "")
        return (f"{self.format}: {where}: {self.cells} cells, {self.from_data} from data, "
                f"{self.interpolated} interpolated, {self.empty} empty ({self.seconds:.2f} s)")


def parse_formats(text: str, field: str = "--export") -> list[str]:
    """A comma-separated list of export formats, validated: e.g. ``"merl,bsdf"`` -> ["merl", "bsdf"].

    Raises
    ------
    ValueError
        Naming ``field``, the unknown format and the allowed ones.
    """
    names = [t.strip() for t in text.split(",") if t.strip()]
    allowed = ", ".join(EXPORT_FORMATS.names())
    if not names:
        raise ValueError(f"{field}: give one or more formats separated by commas; allowed: {allowed}")
    for name in names:
        if name not in EXPORT_FORMATS:
            raise ValueError(f"{field}: format {name!r} is unknown; allowed: {allowed}")
    return list(dict.fromkeys(names))


class ExportJob:
    """What an export format writes from: the data as given, opened the way the format asks for it.

    Attributes
    ----------
    format : str
        The format's name (what its :class:`ExportReport` says).
    source : str, Path, SampledBRDF or MeasuredBRDF
        As given to :func:`export`.
    method : str
        Interpolation of :func:`gonio.brdf.open_brdf` (``brdf``).
    theta_step_deg : float
        Spacing of θ slices, degrees (> 0).
    resolution : int
        N of N × N tables (>= 4).
    """

    def __init__(self, fmt: str, source, *, method: str = "auto", theta_step_deg: float = 5.0,
                 resolution: int = 32):
        self.format, self.source, self.method = fmt, source, method
        self.theta_step_deg, self.resolution = float(theta_step_deg), int(resolution)
        self._brdf = source if isinstance(source, MeasuredBRDF) else None
        self._data = source if isinstance(source, SampledBRDF) else None

    @property
    def data(self) -> SampledBRDF:
        """The measured samples (read on first use); ValueError for an open MeasuredBRDF, which has none."""
        if self._data is None:
            if isinstance(self.source, MeasuredBRDF):
                raise ValueError(f"export format {self.format!r} needs the sampled data (a campaign folder, "
                                 "a brdf.h5 or a SampledBRDF), not an open MeasuredBRDF")
            self._data = read_brdf(_h5_path(self.source))
        return self._data

    @property
    def has_data(self) -> bool:
        """Whether the samples are at hand (anything but an open MeasuredBRDF)."""
        return not isinstance(self.source, MeasuredBRDF)

    @property
    def brdf(self) -> MeasuredBRDF:
        """The measured BRDF to evaluate anywhere (opened with ``method`` on first use)."""
        if self._brdf is None:
            self._brdf = open_brdf(self.data, method=self.method)
        return self._brdf

    def metadata(self, cosine: str) -> dict:
        """Header fields a file format carries: units, the cosine convention, symmetries, source, ..."""
        brdf, a = self.brdf, self.brdf.attrs
        return {"units": "sr^-1", "cosine": cosine,
                "angles": "degrees; theta from +z, phi from the sample's +x",
                "symmetries": json.dumps(brdf.symmetries, sort_keys=True), "source": self.source_name(),
                "material": str(a.get("material", "")), "grid": str(a.get("grid", "")),
                "gantry": str(a.get("gantry", "")),
                "interpolation": f"{brdf.domain}/{brdf.method} (gonio.brdf)",
                "software": f"gonio {software_version()}"}

    def source_name(self) -> str:
        """How the source is named in a file's header."""
        return "in-memory dataset" if isinstance(self.source, SampledBRDF | MeasuredBRDF) \
            else str(self.source)


def export(source, fmt: str, out, *, method: str = "auto", theta_step_deg: float = 5.0,
           resolution: int = 32) -> ExportReport:
    """Export a measured BRDF.

    Parameters
    ----------
    source : str, Path, SampledBRDF or MeasuredBRDF
        A campaign folder, a ``brdf.h5``, data already read, or an open BRDF.
    fmt : str
        A name of :data:`gonio.registries.EXPORT_FORMATS`.
    out : str or Path
        Output file (a folder, created if needed, for ``radiance``). Its folder must exist.
    method : {"auto", "grid", "scattered", "local"}
        Interpolation of :func:`gonio.brdf.open_brdf`.
    theta_step_deg : float
        Spacing of θi slices (``bsdf``) and of θi, θo, φo (``radiance``), degrees (> 0).
    resolution : int
        N of the N × N values per incidence of ``bsdf`` files (>= 4).

    Returns
    -------
    ExportReport
    """
    if fmt not in EXPORT_FORMATS:
        raise ValueError(f"export format {fmt!r} is unknown; allowed: {', '.join(EXPORT_FORMATS.names())}")
    if not theta_step_deg > 0:
        raise ValueError(f"theta_step_deg: must be > 0 degrees, got {theta_step_deg}")
    if int(resolution) < 4:
        raise ValueError(f"resolution: must be an integer >= 4, got {resolution}")
    start = time.perf_counter()
    job = ExportJob(fmt, source, method=method, theta_step_deg=theta_step_deg, resolution=resolution)
    report = EXPORT_FORMATS.load(fmt)(job, Path(out))
    report.format = fmt
    report.seconds = time.perf_counter() - start
    return report


def _h5_path(source) -> Path:
    path = Path(source)
    return path / BRDF_NAME if path.is_dir() else path


def tally(report: ExportReport, ev) -> None:
    """Count the cells of one evaluation ``ev`` (:meth:`gonio.brdf.MeasuredBRDF.eval`) as from data,
    interpolated or empty."""
    ok = ev.reason == Reason.OK
    report.from_data += int(np.count_nonzero(ok & ev.exact))
    report.interpolated += int(np.count_nonzero(ok & ~ev.exact))
    report.empty += int(np.count_nonzero(~ok))


def export_merl(job: ExportJob, out: Path) -> ExportReport:
    """MERL ``.binary``."""
    brdf = job.brdf
    if len(brdf.channels) != 3:
        raise ValueError(f"merl: the format holds R, G, B; the dataset has channels {brdf.channels}")
    ev = brdf.eval_rad(*merl_centre_angles())   # every bin's centre, in the table's order, φh = 0
    report = ExportReport(job.format, cells=MERL_BINS,
                          notes=["f_r in sr^-1, no cosine; stored = f_r * 1500/(1, 1.15, 1.66); -1 = no data",
                                 "MERL files carry no metadata"])
    tally(report, ev)
    report.paths.append(write_merl(out, ev.value.T))
    return report


def _theta_slices(brdf: MeasuredBRDF, step: float) -> np.ndarray:
    top = min(brdf.theta_max_deg, 89.0)
    n = max(2, int(np.ceil(top / step - 1e-9)) + 1)
    return np.linspace(0.0, top, n)


class _Bridge:
    """The scattered engine over a dataset, built on first use (only a campaign with gaps needs it)."""

    def __init__(self, data: SampledBRDF):
        self.data, self.brdf = data, None

    def eval(self, wi, wo):
        if self.brdf is None:
            self.brdf = open_brdf(self.data, method="scattered")
        return self.brdf.eval(wi, wo)


def export_bsdf(job: ExportJob, out: Path) -> ExportReport:
    """The Mitsuba 3 / pbrt-v4 measured-BSDF tensor file, RGB."""
    return _bsdf(job, out, spectral=False)


def export_bsdf_spectral(job: ExportJob, out: Path) -> ExportReport:
    """The tensor file with spectra from R, G, B (:data:`SPECTRAL_NM`)."""
    return _bsdf(job, out, spectral=True)


def _bsdf(job: ExportJob, out: Path, spectral: bool) -> ExportReport:
    """The tensor file. The format has no "no data" value (a 0 is black to a renderer), and every real
    campaign has gaps: the gantry's occlusion clearance leaves retro-reflection unmeasured, and a lattice
    answers NO_DATA in every cell that touches a missing node. So where the lattice has a gap, ``bridge``
    (the scattered engine of :mod:`gonio.brdf` on the same samples, which answers only within the local
    sample spacing) fills in, and the report counts those cells."""
    brdf, fmt = job.brdf, job.format
    bridge = _Bridge(job.data) if job.has_data and brdf.method == "grid" else None
    if len(brdf.channels) != 3:
        raise ValueError(f"{fmt}: written from R, G, B; the dataset has channels {brdf.channels}")
    report = ExportReport(fmt)
    bridged = [0]

    def values(wi, wo, count):
        ev = brdf.eval(wi, wo)
        value = ev.value
        if bridge is not None:
            gap = np.flatnonzero(ev.reason == Reason.NO_DATA)
            if gap.size:
                ev2 = bridge.eval(wi[gap], wo[gap])
                ok = ev2.reason == Reason.OK
                value = value.copy()
                value[gap[ok]] = ev2.value[ok]
                bridged[0] += int(ok.sum()) if count else 0
        return value

    meta = job.metadata("values are f_r*cos(theta_o)*4*sigma(wi)/D(m), jacobian=1 (Mitsuba 3 "
                        "'measured' convention)")
    isotropic = bool(brdf.symmetries["isotropy"])
    retro = _measured_retro(job) if isotropic else None
    if retro is None:
        meta["ndf"] = ("estimated from retro-reflection by fixed-point iteration (gonio.formats.rgl), "
                       f"retro-reflection evaluated through gonio.brdf ({brdf.method})")
        retro = _through(values)
    else:
        meta["ndf"] = ("estimated from retro-reflection by fixed-point iteration (gonio.formats.rgl), "
                       f"retro-reflection from the measured samples within {NEAR_RETRO_DEG:g} deg of it")
    if bridge is not None:
        meta["gaps"] = "cells in gaps of the lattice filled by the scattered engine (gonio.brdf)"
    meta["beyond"] = (f"outgoing directions beyond the data's theta {brdf.theta_max_deg:.1f} deg take f_r at "
                      "the same azimuth on that limit")
    phi = (0.0,) if isotropic else tuple(np.linspace(-180.0, 180.0, 25))
    fields, counts = build_measured(lambda wi, wo: values(wi, wo, True),
                                    theta_i_deg=_theta_slices(brdf, job.theta_step_deg), phi_i_deg=phi,
                                    resolution=job.resolution, spectral_nm=SPECTRAL_NM if spectral else None,
                                    description=meta, retro_fr=retro, theta_max_deg=brdf.theta_max_deg)
    # Only the value grid counts (the retro-reflection probes of the NDF estimate are not cells).
    report.cells = counts["points"]
    report.interpolated = counts["filled"]
    report.empty = counts["empty"]
    report.notes = [meta["cosine"], meta["ndf"]]
    if counts["extended"]:
        report.notes.append(f"{counts['extended']} of the {counts['filled']} filled cells look beyond the "
                            f"data's theta {brdf.theta_max_deg:.1f} deg: f_r at that azimuth on the limit")
    if bridged[0]:
        report.notes.append(f"{bridged[0]} of the {counts['filled']} filled cells lie in gaps of the lattice "
                            "(unmeasured poses, e.g. retro-reflection): filled by the scattered engine")
    report.paths.append(write_tensor(out, fields))
    return report


def _through(values):
    """f_r(ω, ω) through ``values`` (the export's evaluation), not counted as cells."""
    return lambda w: values(w, w, False)


def _measured_retro(job: ExportJob):
    """The retro-reflection profile of the job's measured samples
    (:func:`gonio.formats.rgl.retro_from_samples`), or None: an open MeasuredBRDF (no samples), or too few
    samples near retro-reflection."""
    if not job.has_data:
        return None
    data = job.data
    wi = sph_to_vec(np.radians(data.theta_i), np.radians(data.phi_i))
    wo = sph_to_vec(np.radians(data.theta_o), np.radians(data.phi_o))
    profile = retro_from_samples(wi, wo, data.value)
    return None if profile is None else (lambda w: np.repeat(profile(w)[:, None], 3, axis=1))


def export_radiance(job: ExportJob, out: Path) -> ExportReport:
    """A folder of PAB-Opto files, one per incidence."""
    if not out.parent.is_dir():
        raise ValueError(f"output {str(out)!r}: folder {str(out.parent)!r} does not exist")
    if out.exists() and not out.is_dir():
        raise ValueError(f"output {str(out)!r}: is a file; radiance exports write a folder of files")
    # Written under a temporary name and renamed into place: never a half-written set of incidences.
    tmp = out.with_name(f".{out.name}.{os.getpid()}.partial")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    try:
        report = _radiance_files(job, tmp)
        old = out.with_name(f".{out.name}.{os.getpid()}.old")
        if out.exists():
            out.rename(old)
        tmp.rename(out)
        shutil.rmtree(old, ignore_errors=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    report.paths = [out / p.name for p in report.paths]
    return report


def _radiance_files(job: ExportJob, out: Path) -> ExportReport:
    brdf, step = job.brdf, job.theta_step_deg
    meta = job.metadata("none: BRDF (f_r); a DSF would include cos(theta_o)")
    top = min(brdf.theta_max_deg, 89.0)
    thetas = np.arange(0.0, top + 1e-9, step)
    phis = np.arange(0.0, 360.0 - 1e-9, step)
    to, po = (a.ravel() for a in np.meshgrid(thetas, phis, indexing="ij"))
    keep = (to > 0) | (po == 0)  # one azimuth at the pole
    to, po = to[keep], po[keep]
    incidences = [(t, 0.0) for t in thetas] if brdf.symmetries["isotropy"] else \
        [(t, p) for t in thetas for p in (phis if t > 0 else [0.0])]
    bands = brdf.attrs.get("wavelengths_nm")
    if bands is not None and len(bands) == len(brdf.channels):  # a spectrometer's campaign
        from gonio.colour import bands_to_XYZ

        note = f"CIE-Y (1931 2 deg, D65) of the {len(bands)} spectral bands"

        def luminance(v):
            return bands_to_XYZ(v, bands)[..., 1]
    else:
        weights = np.asarray(LUMINANCE_WEIGHTS) if len(brdf.channels) == 3 else None
        note = (f"CIE-Y = {LUMINANCE_WEIGHTS} . (R, G, B)" if weights is not None else
                f"the channel {brdf.channels[0]!r} as measured (no colour weighting)")

        def luminance(v):
            return v @ weights if weights is not None else v[:, 0]
    report = ExportReport(job.format, notes=[note, meta["cosine"]])
    for t, p in incidences:
        ev = brdf.eval_deg(t, p, to, po)
        tally(report, ev)
        y = luminance(ev.value)
        name = out / f"incidence_t{t:05.1f}_p{p:05.1f}.pabopto.dat"
        report.paths.append(write_pabopto(name, t, p, to, po, y, sample_name=meta["material"] or "gonio",
                                          metadata=meta))
    report.cells = report.from_data + report.interpolated + report.empty
    return report


def export_csv(job: ExportJob, out: Path) -> ExportReport:
    """The measured samples, one row each."""
    data = job.data
    angles = np.stack([np.asarray(a, dtype=np.float64).ravel() for a in
                       (data.theta_i, data.phi_i, data.theta_o, data.phi_o)], axis=1)
    value = np.asarray(data.value, dtype=np.float64).reshape(len(angles), -1)
    channels = data.attrs.get("channels")
    channels = [str(c) for c in channels] if channels is not None and len(channels) == value.shape[1] else \
        [f"c{i}" for i in range(value.shape[1])]
    symmetries = data.attrs.get("symmetries", {})
    meta = {"cosine": "none (f_r)", "symmetries": json.dumps(symmetries, sort_keys=True) if isinstance(
        symmetries, dict) else str(symmetries), "source": job.source_name(),
        "material": str(data.attrs.get("material", "")),
        "grid": str(data.attrs.get("grid", "")), "software": f"gonio {software_version()}"}
    path = write_csv(out, angles, value, data.stddev, channels=channels, metadata=meta)
    finite = np.isfinite(value).all(axis=1)
    return ExportReport(job.format, [path], len(angles), int(finite.sum()), 0, int((~finite).sum()),
                        notes=["one row per measured sample; f_r in sr^-1, no cosine"])


def export_h5(job: ExportJob, out: Path) -> ExportReport:
    """The sampled dataset itself (a copy of ``brdf.h5``, or the dataset written)."""
    data = job.data
    n = int(np.asarray(data.theta_i).size)
    if not isinstance(job.source, SampledBRDF):
        with atomic_path(out) as tmp:
            shutil.copyfile(_h5_path(job.source), tmp)
    else:
        write_brdf(out, data)
    return ExportReport(job.format, [out], n, n, 0, 0,
                        notes=["the sampled dataset (brdf.h5 layout) as it is"])
