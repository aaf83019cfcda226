"""Comma-separated samples: one row per direction pair, a header that gives the units.

Layout::

    # gonio sampled BRDF
    # units: angles in degrees; fr and stddev in sr^-1; no cosine factor
    # key: value              (symmetries, source, material, grid, software_version, ...)
    theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,fr_R_sr-1,fr_G_sr-1,fr_B_sr-1,stddev_R_sr-1,...
    0,0,10,0,0.159,0.159,0.159,0,0,0

Angles follow DESIGN.md (θ from the normal +z, φ from the sample's +x, ωi toward the light).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from . import atomic_path

__all__ = ["write_csv", "read_csv"]

_ANGLES = ("theta_i_deg", "phi_i_deg", "theta_o_deg", "phi_o_deg")


def write_csv(path: str | Path, angles_deg, value, stddev, *, channels=("R", "G", "B"),
              metadata: dict | None = None) -> Path:
    """Write samples as CSV (atomically).

    Parameters
    ----------
    path : str or Path
        Output file.
    angles_deg : array_like, shape (N, 4)
        θi, φi, θo, φo in degrees.
    value, stddev : array_like, shape (N, C)
        f_r and its standard deviation in sr⁻¹, no cosine factor.
    channels : sequence of str
        Channel names (C of them), used in the column names.
    metadata : dict, optional
        ``# key: value`` header lines.

    Returns
    -------
    Path
        ``path``.
    """
    angles = np.asarray(angles_deg, dtype=np.float64).reshape(-1, 4)
    value = np.asarray(value, dtype=np.float64).reshape(len(angles), -1)
    stddev = np.asarray(stddev, dtype=np.float64).reshape(value.shape)
    channels = list(channels)
    if len(channels) != value.shape[1]:
        raise ValueError(f"csv: {len(channels)} channel names for {value.shape[1]} value columns")
    head = ["# gonio sampled BRDF",
            "# units: angles in degrees; fr and stddev in sr^-1; no cosine factor "
            "(fr_cos = fr * cos(theta_o))"]
    for key, text in (metadata or {}).items():
        head.append(f"# {key}: {' '.join(str(text).split())}")
    cols = list(_ANGLES) + [f"fr_{c}_sr-1" for c in channels] + [f"stddev_{c}_sr-1" for c in channels]
    head.append(",".join(cols))
    path = Path(path)
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8") as fh:
        fh.write("\n".join(head) + "\n")
        np.savetxt(fh, np.hstack([angles, value, stddev]), fmt="%.17g", delimiter=",")
    return path


def read_csv(path: str | Path) -> dict:
    """Read a file written by :func:`write_csv`.

    Returns
    -------
    dict
        ``angles_deg`` (N, 4), ``value`` and ``stddev`` (N, C), ``channels`` and ``metadata``.
    """
    path = Path(path)
    metadata, header = {}, None
    with open(path, encoding="utf-8") as fh:
        for line in fh:
            if line.startswith("#"):
                key, sep, text = line[1:].strip().partition(":")
                if sep:
                    metadata[key.strip()] = text.strip()
                continue
            header = line.strip().split(",")
            break
        if header is None or header[:4] != list(_ANGLES):
            raise ValueError(f"csv {str(path)!r}: expected a column header starting with {','.join(_ANGLES)}")
        data = np.loadtxt(fh, delimiter=",", ndmin=2)
    n_channels = (len(header) - 4) // 2
    channels = [h[3:-5] for h in header[4:4 + n_channels]]
    return {"angles_deg": data[:, :4], "value": data[:, 4:4 + n_channels],
            "stddev": data[:, 4 + n_channels:], "channels": channels, "metadata": metadata}
