"""The sampled BRDF of a campaign: ``brdf.h5`` in the campaign folder.

Layout (read it with any HDF5 reader):
- ``samples/theta_i``, ``samples/phi_i``, ``samples/theta_o``, ``samples/phi_o``: (N,) float64, degrees,
  the actual measured directions (forward kinematics of the read-back axis positions);
- ``samples/value``, ``samples/stddev``: (N, C) float64, f_r in sr⁻¹ (no cosine factor);
- ``samples/pose``: (N,) the plan's pose index of each sample; ``samples/step``: (N,) its journal step;
- ``samples/campaign_s``: (N,) float64, the campaign clock at the reading (s, continuous across resumes);
- attributes ``units`` ("sr^-1"), ``channels``, ``symmetries`` (JSON: the shortcuts the plan used),
  ``grid``, ``material`` (simulated) or ``sample`` (real), ``seed``, ``config_sha256``, ``gantry``,
  ``software_version``, ``format`` ("gonio-brdf"), ``format_version``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from gonio.calibrate import Calibrated

__all__ = ["BRDF_NAME", "SampledBRDF", "write_brdf", "read_brdf"]

BRDF_NAME = "brdf.h5"
FORMAT_VERSION = 1


@dataclass(frozen=True)
class SampledBRDF:
    theta_i: np.ndarray
    phi_i: np.ndarray
    theta_o: np.ndarray
    phi_o: np.ndarray
    value: np.ndarray
    stddev: np.ndarray
    attrs: dict


def write_brdf(path: str | Path, cal: Calibrated, *, channels, symmetries: dict, grid: str, material: str,
               gantry: str, software_version: str, seed: int = 0, sample: str = "",
               config_sha256: str = "") -> Path:
    path = Path(path)
    tmp = path.with_suffix(".h5.partial")
    with h5py.File(tmp, "w") as f:
        g = f.create_group("samples")
        for i, name in enumerate(("theta_i", "phi_i", "theta_o", "phi_o")):
            g.create_dataset(name, data=cal.angles_deg[:, i].astype(np.float64))
        g.create_dataset("value", data=cal.value.astype(np.float64))
        g.create_dataset("stddev", data=cal.stddev.astype(np.float64))
        g.create_dataset("pose", data=cal.poses.astype(np.int64))
        g.create_dataset("step", data=cal.steps.astype(np.int64))
        g.create_dataset("campaign_s", data=cal.campaign_s.astype(np.float64))
        f.attrs.update({
            "format": "gonio-brdf", "format_version": FORMAT_VERSION, "units": "sr^-1",
            "channels": list(channels), "symmetries": json.dumps(symmetries), "grid": grid,
            "material": material, "sample": sample, "seed": int(seed), "config_sha256": config_sha256,
            "gantry": gantry, "software_version": software_version,
            "angles_units": "degrees",
        })
    tmp.replace(path)  # never leave a half-written brdf.h5 behind
    return path


def read_brdf(path: str | Path) -> SampledBRDF:
    with h5py.File(path, "r") as f:
        g = f["samples"]
        attrs = {k: (v.decode() if isinstance(v, bytes) else v) for k, v in f.attrs.items()}
        attrs["symmetries"] = json.loads(attrs["symmetries"])
        return SampledBRDF(*(g[n][()] for n in ("theta_i", "phi_i", "theta_o", "phi_o", "value", "stddev")),
                           attrs=attrs)
