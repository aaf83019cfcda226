"""The sampled BRDF of a campaign: ``brdf.h5`` in the campaign folder (format version 2).

An HDF5 file that h5py reads as it is and that netCDF-4 readers read with named dimensions: every array
of group ``samples`` has HDF5 dimension scales attached, so ``xarray.open_dataset(path,
engine="h5netcdf", group="samples")`` shows dimensions ``sample``, ``channel`` (and ``grid_axis``), the
angles, steps and times as coordinates, and the units as attributes.

Group ``samples`` (N samples, C channels):

==============================  ================  ========  ============================================
variable                        dimensions        units     what
==============================  ================  ========  ============================================
``sample``                      (sample)          1         0..N-1 (dimension scale)
``channel``                     (channel)         –         channel names, e.g. R, G, B (dimension scale)
``theta_i`` ``phi_i``           (sample)          degree    measured directions: forward kinematics of
``theta_o`` ``phi_o``                                       the axis positions read back after settling
``theta_i_planned`` … ``phi_o``  (sample)          degree    the plan's directions for the sample's step
``value``                       (sample, channel) sr^-1     f_r, no cosine factor
``stddev``                      (sample, channel) sr^-1     its standard deviation (1 σ)
``step`` ``pose``               (sample)          1         journal step, plan pose index
``exposure_s``                  (sample)          s         exposure of the reading
``campaign_s``                  (sample)          s         campaign clock at the reading (continues
                                                            across resumes)
``wavelength``                  (channel)         nm        centre of each band (spectrometer campaigns
                                                            only; also the file attribute
                                                            ``wavelengths_nm``)
``grid_index``                  (sample,          1         the planned pose's indices on the grid
                                grid_axis)                  (``grid_axis`` names them; iso: θi, θo, Δφ
                                                            in steps; full: θi, φi, θo, φo in steps;
                                                            merl: θh, θd, φd bin numbers); only for
                                                            grids that have them
==============================  ================  ========  ============================================

Attributes (on the file and on the group, so that a reader of either sees them): ``format``
("gonio-brdf"), ``format_version`` (2), ``units`` ("sr^-1"), ``cosine`` ("none"), ``angles_units``
("degrees"), ``frame`` and ``angle_convention`` (docs/conventions.md), ``channels``, ``color_space``,
``symmetries`` (JSON: the shortcuts the plan used), ``grid``, ``gantry``, ``reference_albedo`` (the
config's albedo of the white standard) and, where the standard was given per channel, as a spectrum or
with an angular response, ``reference_reflectance`` (ρ_ref · response per channel: what the calibration
divided by, in place of ``reference_albedo``), ``source_half_angle_deg`` and ``detector_half_angle_deg``
(the half-angles of the cones the source subtends and the detector sees, which every reading averages
over: written for a simulated campaign's photodiode or spectrometer, from ``[light.sim]`` and
``[detector.sim]``; :func:`aperture_cones` reads them, or for older files the config snapshot), ``seed``,
``software_version``, ``config_sha256`` and ``config`` (JSON: the config snapshot the campaign was
planned with), ``created_unix``/``created_utc`` (campaign creation), ``written_unix``, and either
``material`` (the simulated material's spec; ``source`` = "simulated") or ``sample`` (a real sample's
name; ``source`` = "measured").

Version 1 files (the same ``samples`` group without dimension scales, planned angles, exposures or grid
indices) are still read by :func:`read_brdf`.
"""

from __future__ import annotations

import datetime as _dt
import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gonio.geometry import HALF_PI, MERL_SHAPE, sph_to_vec, to_half_diff, to_isotropic

__all__ = ["BRDF_NAME", "FORMAT_VERSION", "SampledBRDF", "write_brdf", "read_brdf", "campaign_dataset",
           "calibration_reference", "aperture_cones", "CONE_DETECTORS", "grid_indices", "FRAME",
           "ANGLE_CONVENTION"]

BRDF_NAME = "brdf.h5"
FORMAT_VERSION = 2
GROUP = "samples"
_ANGLES = ("theta_i", "phi_i", "theta_o", "phi_o")
FRAME = "+z the sample normal, +x the sample's reference direction (e.g. brushing), right-handed"
ANGLE_CONVENTION = ("theta: polar angle from +z; phi: azimuth counter-clockwise from +x seen from above; "
                    "w_i points toward the light, w_o toward the detector; the mirror direction of "
                    "(theta_i, phi_i) is (theta_i, phi_i + 180)")
_RGB_SPACE = "linear RGB, Rec. 709 (sRGB) primaries, D65 white, no transfer function"
_GRID_AXES = {"iso": ("theta_i", "theta_o", "dphi"), "full": _ANGLES, "merl": ("theta_h", "theta_d", "phi_d")}
# Attributes kept as JSON text in the file (HDF5 attributes hold no nested data).
_JSON_ATTRS = ("symmetries", "config")


@dataclass(frozen=True)
class SampledBRDF:
    """Sampled f_r as stored in ``brdf.h5``.

    Attributes
    ----------
    theta_i, phi_i, theta_o, phi_o : numpy.ndarray, shape (N,)
        Measured directions, degrees.
    value, stddev : numpy.ndarray, shape (N, C)
        f_r and its standard deviation, sr⁻¹ (no cosine factor).
    attrs : dict
        The file's attributes (``symmetries`` and ``config`` decoded from JSON).
    planned : numpy.ndarray, shape (N, 4), or None
        The plan's (θi, φi, θo, φo) of each sample, degrees (None in version 1 files).
    step, pose : numpy.ndarray of int64, shape (N,), or None
        Journal step and plan pose index.
    exposure_s, campaign_s : numpy.ndarray, shape (N,), or None
        Exposure and campaign clock of each reading, seconds.
    grid_index : numpy.ndarray of int64, shape (N, K), or None
        Grid indices of each planned pose; ``grid_axes`` names the K columns.
    """

    theta_i: np.ndarray
    phi_i: np.ndarray
    theta_o: np.ndarray
    phi_o: np.ndarray
    value: np.ndarray
    stddev: np.ndarray
    attrs: dict
    planned: np.ndarray | None = None
    step: np.ndarray | None = None
    pose: np.ndarray | None = None
    exposure_s: np.ndarray | None = None
    campaign_s: np.ndarray | None = None
    grid_index: np.ndarray | None = None
    grid_axes: tuple = field(default=())


def color_space(channels) -> str:
    """The colour space of a channel list: linear Rec. 709 for R, G, B (the house's RGB, also what the
    Radiance export's luminance weights assume), the detector's own bands otherwise."""
    return _RGB_SPACE if tuple(channels) == ("R", "G", "B") else "detector bands (see the gantry config)"


def calibration_reference(attrs: dict):
    """The white standard's reflectance a brdf.h5 was calibrated with, from its attributes ``attrs``:
    ``reference_reflectance`` (ρ_ref · response, one per channel) where the file has it, else
    ``reference_albedo`` (one number); None where it has neither (a file not written by a campaign).
    :func:`gonio.calibrate.calibrate` of the campaign's journal with it gives the file's values."""
    if attrs.get("reference_reflectance") is not None:
        return np.asarray(attrs["reference_reflectance"], dtype=np.float64)
    albedo = attrs.get("reference_albedo")
    return None if albedo is None else float(albedo)


#: Simulated detectors whose reading is the aperture average of :mod:`gonio.sim.aperture` (a camera's
#: pixels see other cones).
CONE_DETECTORS = ("photodiode", "spectrometer")


def aperture_cones(attrs: dict) -> tuple[float, float] | None:
    """(source, detector) cone half-angles in degrees that the values of a brdf.h5 were measured through,
    from its attributes ``attrs``: ``source_half_angle_deg`` and ``detector_half_angle_deg`` where the file
    has them; else, for a simulated campaign's file written before they were recorded, its config
    snapshot (``[light.sim]``, ``[detector.sim]``; the snapshot leaves out defaults); None where they are
    not known (a real sample's file without them, a simulated camera, a file not written by a campaign)."""
    names = ("source_half_angle_deg", "detector_half_angle_deg")
    if all(attrs.get(n) is not None for n in names):
        out = []
        for n in names:
            v = attrs[n]
            if isinstance(v, bool) or not isinstance(v, int | float | np.number):
                raise ValueError(f"{n}: must be a number in (0, 10] degrees, got {v!r}")
            out.append(float(v))
        return out[0], out[1]
    config = attrs.get("config")
    if not attrs.get("material") or not isinstance(config, dict):
        return None
    from gonio.device_config import DetectorSimConfig, LightSimConfig

    light = (config.get("light") or {}).get("sim") or {}
    detector = (config.get("detector") or {}).get("sim") or {}
    if detector.get("kind", DetectorSimConfig.model_fields["kind"].default) not in CONE_DETECTORS:
        return None
    key = "half_angle_deg"
    try:
        return (float(light.get(key, LightSimConfig.model_fields[key].default)),
                float(detector.get(key, DetectorSimConfig.model_fields[key].default)))
    except (TypeError, ValueError):
        return None


def grid_indices(grid: str, planned_deg: np.ndarray) -> tuple[np.ndarray, tuple[str, ...]] | None:
    """Indices of planned directions on the campaign's grid, or None where the grid has none.

    Parameters
    ----------
    grid : str
        The GRID string the plan used (``iso:step=...``, ``full:step=...``, ``merl:stride=...``).
    planned_deg : numpy.ndarray, shape (N, 4)
        Planned (θi, φi, θo, φo), degrees.

    Returns
    -------
    (numpy.ndarray of int64, shape (N, K), tuple of K axis names) or None
        iso: (θi, θo, Δφ) / step; full: (θi, φi, θo, φo) / step; merl: (θh, θd, φd) MERL bin numbers
        (φd over 360 bins without reciprocity). None for an unknown grid, a grid of scattered poses
        (adaptive) or directions off its lattice.
    """
    from gonio.plan.grids import parse_grid

    try:
        spec = parse_grid(grid)
    except ValueError:
        return None
    if spec.kind not in _GRID_AXES:   # scattered poses (adaptive): no lattice to index
        return None
    p = np.asarray(planned_deg, dtype=np.float64).reshape(-1, 4)
    if not np.isfinite(p).all():
        return None
    r = np.radians(p)
    if spec.kind == "merl":
        th, _, td, pd = to_half_diff(sph_to_vec(r[:, 0], r[:, 1]), sph_to_vec(r[:, 2], r[:, 3]))
        nh, nd, nphi = MERL_SHAPE
        period = np.pi if spec.reciprocity else 2.0 * np.pi
        ih = np.floor(np.sqrt(np.clip(th, 0.0, None) / HALF_PI) * nh)
        id_ = np.floor(td / HALF_PI * nd)
        ip = np.floor(np.mod(pd, period) / np.pi * nphi)
        idx = np.stack([ih, id_, ip], axis=1)
    else:
        if spec.kind == "iso":
            ti, to, dphi = to_isotropic(r[:, 0], r[:, 1], r[:, 2], r[:, 3])
            x = np.degrees(np.stack([ti, to, dphi], axis=1)) / spec.step_deg
        else:
            x = np.stack([p[:, 0], np.mod(p[:, 1], 360.0), p[:, 2], np.mod(p[:, 3], 360.0)], 1)
            x = x / spec.step_deg
        idx = np.rint(x)
        if np.abs(x - idx).max(initial=0.0) > 1e-6:
            return None
        turns = round(360.0 / spec.step_deg)
        for k, name in enumerate(_GRID_AXES[spec.kind]):
            if name in ("dphi", "phi_i", "phi_o"):
                idx[:, k] = np.mod(idx[:, k], turns)
    return idx.astype(np.int64), _GRID_AXES[spec.kind]


def campaign_dataset(cal, steps: dict, meta: dict, *, exposure_s, reference_albedo: float,
                     software_version: str, reference_reflectance=None, cones=None) -> SampledBRDF:
    """The dataset of a finished campaign, from its calibration and its journal.

    Parameters
    ----------
    cal : gonio.calibrate.Calibrated
        Calibrated pose samples.
    steps : dict
        The journal's steps table (:meth:`gonio.store.Journal.steps`): planned angles per step.
    meta : dict
        The journal's meta (grid, material, sample, seed, symmetries, config, ...).
    exposure_s : array_like, shape (N,)
        Exposure of each sample's reading, seconds.
    reference_albedo : float
        Hemispherical reflectance of the white standard used for the calibration.
    reference_reflectance : array_like, shape (C,), optional
        ρ_ref · response per channel (π times the standard's f_r where it was read), where the config
        gave a reflectance per channel, a spectrum or a response other than 1 (attribute
        ``reference_reflectance``).
    software_version : str
        The gonio version writing the file.
    cones : (float, float), optional
        Half-angles (degrees) of the source's and the detector's cones, where they are known
        (attributes ``source_half_angle_deg``, ``detector_half_angle_deg``).
    """
    n = len(cal.value)
    planned = np.stack([np.asarray(steps[f"{a}_deg"], float)[cal.steps] for a in _ANGLES], axis=1) \
        if n else np.zeros((0, 4))
    found = grid_indices(meta["grid"], planned) if n else None
    channels = [str(c) for c in meta["channels"]]
    created = float(meta.get("created_unix") or 0.0)
    material, sample = meta.get("material") or "", meta.get("sample") or ""
    attrs = {
        "channels": channels, "color_space": color_space(channels), "symmetries": dict(meta["symmetries"]),
        "grid": meta["grid"], "gantry": meta["gantry"], "reference_albedo": float(reference_albedo),
        "seed": int(meta["seed"]), "software_version": software_version,
        "config_sha256": meta.get("config_sha256", ""), "config": meta.get("config", {}),
        "created_unix": created,
        "created_utc": _dt.datetime.fromtimestamp(created, _dt.UTC).isoformat(timespec="seconds"),
        "material": material, "sample": sample, "source": "simulated" if material else "measured",
    }
    if cones is not None:
        attrs["source_half_angle_deg"], attrs["detector_half_angle_deg"] = (float(a) for a in cones)
    if reference_reflectance is not None:
        attrs["reference_reflectance"] = [float(r) for r in np.asarray(reference_reflectance, float)]
    wavelengths = (meta.get("detector") or {}).get("wavelengths_nm")
    if wavelengths is not None:  # a spectrometer's bands
        attrs["wavelengths_nm"] = [float(w) for w in wavelengths]
        attrs["color_space"] = "spectral (one channel per band of wavelengths_nm)"
    return SampledBRDF(
        *(cal.angles_deg[:, k].astype(np.float64) for k in range(4)),
        value=cal.value.astype(np.float64), stddev=cal.stddev.astype(np.float64), attrs=attrs,
        planned=planned, step=np.asarray(cal.steps, np.int64), pose=np.asarray(cal.poses, np.int64),
        exposure_s=np.asarray(exposure_s, np.float64).reshape(n),
        campaign_s=np.asarray(cal.campaign_s, np.float64),
        grid_index=None if found is None else found[0], grid_axes=() if found is None else found[1])


def _file_attrs(data: SampledBRDF, n_channels: int) -> dict:
    a = dict(data.attrs)
    channels = [str(c) for c in a.get("channels", [])]
    if len(channels) != n_channels:
        channels = ["R", "G", "B"] if n_channels == 3 else [f"c{i}" for i in range(n_channels)]
    a.update({
        "format": "gonio-brdf", "format_version": FORMAT_VERSION, "units": "sr^-1", "cosine": "none",
        "angles_units": "degrees", "frame": FRAME, "angle_convention": ANGLE_CONVENTION,
        "channels": channels, "written_unix": time.time(),
    })
    a.setdefault("color_space", color_space(channels))
    out = {}
    for key, val in a.items():
        if key in _JSON_ATTRS or isinstance(val, dict):
            val = val if isinstance(val, str) else json.dumps(val, sort_keys=True)
        elif isinstance(val, bool | np.bool_):
            val = int(val)  # HDF5 has no boolean; netCDF readers choke on h5py's enum for it
        elif val is None:
            continue
        out[key] = val
    return out


def write_brdf(path: str | Path, data: SampledBRDF) -> Path:
    """Write ``data`` as a version 2 ``brdf.h5`` at ``path``, atomically (a temporary name in the same
    folder renamed into place: readers never see a half-written file).

    Parameters
    ----------
    path : str or Path
        Output file; its folder must exist.
    data : SampledBRDF
        Angles in degrees, f_r in sr⁻¹; the optional arrays are written when present.

    Returns
    -------
    Path
    """
    import h5py  # here, not at the top: reading a campaign's state (gonio status) needs no HDF5

    from gonio.formats import atomic_path

    path = Path(path)
    value = np.asarray(data.value, dtype=np.float64)
    n = int(np.asarray(data.theta_i).size)
    value = value.reshape(n, -1)
    attrs = _file_attrs(data, value.shape[1])
    with atomic_path(path) as tmp, h5py.File(tmp, "w") as f:
        g = f.create_group(GROUP)
        sample = g.create_dataset("sample", data=np.arange(n, dtype=np.int64))
        sample.make_scale("sample")
        sample.attrs.update({"long_name": "sample number", "units": "1"})
        channel = g.create_dataset("channel", data=np.array(attrs["channels"], dtype=h5py.string_dtype()))
        channel.make_scale("channel")
        channel.attrs.update({"long_name": "detector channel", "color_space": attrs["color_space"]})
        coords = []
        wavelengths = attrs.get("wavelengths_nm")
        if wavelengths is not None and len(wavelengths) == value.shape[1]:
            wl = g.create_dataset("wavelength", data=np.asarray(wavelengths, np.float64))
            wl.dims[0].attach_scale(channel)
            wl.attrs.update({"units": "nm", "long_name": "centre wavelength of the channel's band"})
            coords.append("wavelength")

        def put(name, arr, dims, **var_attrs):
            ds = g.create_dataset(name, data=arr)
            for k, scale in enumerate(dims):
                ds.dims[k].attach_scale(scale)
            ds.attrs.update(var_attrs)

        for name in _ANGLES:
            put(name, np.asarray(getattr(data, name), np.float64).reshape(n), [sample], units="degree",
                long_name=f"measured {name} (forward kinematics of the read-back axes)")
            coords.append(name)
        if data.planned is not None:
            for k, name in enumerate(_ANGLES):
                put(f"{name}_planned", np.asarray(data.planned, np.float64)[:, k], [sample], units="degree",
                    long_name=f"planned {name} (the journal's steps table)")
                coords.append(f"{name}_planned")
        for name, unit, what in (("step", "1", "journal step"), ("pose", "1", "plan pose index"),
                                 ("exposure_s", "s", "exposure of the reading"),
                                 ("campaign_s", "s", "campaign clock at the end of the reading")):
            arr = getattr(data, name)
            if arr is not None:
                dtype = np.int64 if unit == "1" else np.float64
                put(name, np.asarray(arr, dtype).reshape(n), [sample], units=unit, long_name=what)
                coords.append(name)
        if data.grid_index is not None:
            axis = g.create_dataset("grid_axis", data=np.array(data.grid_axes, dtype=h5py.string_dtype()))
            axis.make_scale("grid_axis")
            put("grid_index", np.asarray(data.grid_index, np.int64).reshape(n, -1), [sample, axis], units="1",
                long_name="the planned pose's indices on the grid (grid_axis names them)", grid=attrs.get(
                    "grid", ""))
        for name, arr, what in (("value", value, "f_r, no cosine factor"),
                                ("stddev", data.stddev, "standard deviation of f_r (1 sigma)")):
            put(name, np.asarray(arr, np.float64).reshape(value.shape), [sample, channel], units="sr^-1",
                long_name=what, coordinates=" ".join(coords))
        f.attrs.update(attrs)
        g.attrs.update(attrs)
    return path


def _decode(val):
    if isinstance(val, bytes):
        return val.decode()
    if isinstance(val, np.ndarray) and val.dtype.kind in "OS":
        return [v.decode() if isinstance(v, bytes) else str(v) for v in val]
    if isinstance(val, np.generic):
        return val.item()
    return val


def read_brdf(path: str | Path) -> SampledBRDF:
    """Read a ``brdf.h5`` of format version 1 or 2.

    Raises
    ------
    ValueError
        The file is not a gonio BRDF dataset, or of a newer format version.
    """
    import h5py

    path = Path(path)
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise ValueError(f"{path}: not an HDF5 file ({exc})") from None
    with f:
        if GROUP not in f or "value" not in f[GROUP]:
            raise ValueError(f"{path}: not a gonio BRDF dataset (no '{GROUP}/value')")
        version = int(f.attrs.get("format_version", 1))
        if version > FORMAT_VERSION:
            raise ValueError(f"{path}: brdf.h5 format version {version}; this gonio reads versions 1 to "
                             f"{FORMAT_VERSION}")
        g = f[GROUP]
        attrs = {k: _decode(v) for k, v in f.attrs.items()}
        for key in _JSON_ATTRS:
            if isinstance(attrs.get(key), str) and attrs[key].strip():
                attrs[key] = json.loads(attrs[key])
        get = lambda name: g[name][()] if name in g else None  # noqa: E731
        planned = None
        if all(f"{a}_planned" in g for a in _ANGLES):
            planned = np.stack([g[f"{a}_planned"][()] for a in _ANGLES], axis=1)
        grid_axes = tuple(_decode(g["grid_axis"][()])) if "grid_axis" in g else ()
        return SampledBRDF(*(g[n][()] for n in (*_ANGLES, "value", "stddev")), attrs=attrs, planned=planned,
                           step=get("step"), pose=get("pose"), exposure_s=get("exposure_s"),
                           campaign_s=get("campaign_s"), grid_index=get("grid_index"), grid_axes=grid_axes)
