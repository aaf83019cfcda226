"""PAB-Opto text files, one per incidence, as Radiance's ``pabopto2bsdf`` reads them.

Each file (shared/references/FORMATS.md; LBNL-ETA/Radiance ``src/cv/pabopto2bsdf.c``)::

    #sample_name "gold"
    #format: theta phi BRDF
    #incident_angle 30 0
    #colorimetry: CIE-Y
    #gonio ...                (our metadata: other '#' lines are ignored by the reader)
    0 0 0.1234
    5 0 0.1240
    ...

Rows are ``θo φo value`` in degrees; "BRDF" values are f_r in sr⁻¹ without the cosine factor (a "DSF"
file would include it). The format is monochrome here: CIE-Y, the luminance of linear R, G, B with the
Rec. 709 / sRGB weights 0.2126, 0.7152, 0.0722 (one channel is written as it is). Azimuths are ours (from
the sample's +x axis), so ``#upphi`` is left at its default 0. Unsupported directions are left out.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from . import atomic_path

__all__ = ["write_pabopto", "read_pabopto", "LUMINANCE_WEIGHTS"]

#: Weights of linear R, G, B in CIE Y (Rec. 709 primaries, D65).
LUMINANCE_WEIGHTS = (0.2126, 0.7152, 0.0722)


def _number(x: float) -> str:
    return f"{x:.10g}"


def write_pabopto(path: str | Path, theta_i_deg: float, phi_i_deg: float, theta_o_deg, phi_o_deg, value, *,
                  sample_name: str = "gonio", metadata: dict | None = None) -> Path:
    """Write one incidence as a PAB-Opto BRDF file (atomically).

    Parameters
    ----------
    path : str or Path
        Output file (``*.dat`` by Radiance's habit; name it so it is not mistaken for MIT data).
    theta_i_deg, phi_i_deg : float
        Incidence in degrees.
    theta_o_deg, phi_o_deg : array_like, shape (M,)
        Outgoing directions in degrees.
    value : array_like, shape (M,)
        f_r in sr⁻¹ (CIE-Y), no cosine factor; rows that are not finite are left out.
    sample_name : str
        Written as ``#sample_name``.
    metadata : dict, optional
        Written as ``#gonio key: value`` lines (units, cosine, symmetries, source, software).

    Returns
    -------
    Path
        ``path``.
    """
    to, po, v = (np.asarray(a, dtype=np.float64).ravel() for a in (theta_o_deg, phi_o_deg, value))
    keep = np.isfinite(v) & np.isfinite(to) & np.isfinite(po)
    lines = [f'#sample_name "{sample_name}"', "#format: theta phi BRDF",
             f"#incident_angle {_number(theta_i_deg)} {_number(phi_i_deg)}", "#colorimetry: CIE-Y"]
    for key, text in (metadata or {}).items():
        lines.append(f"#gonio {key}: {' '.join(str(text).split())}")
    rows = np.stack([to[keep], po[keep], v[keep]], axis=1)
    path = Path(path)
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8") as fh:
        fh.write("\n".join(lines) + "\n")
        np.savetxt(fh, rows, fmt="%.10g")
    return path


def read_pabopto(path: str | Path) -> dict:
    """Read a PAB-Opto file written by :func:`write_pabopto` (or by another tool, BRDF or DSF format).

    Returns
    -------
    dict
        ``theta_i_deg``, ``phi_i_deg`` (floats), ``format`` ("BRDF", "BSDF", "BTDF" or "DSF"),
        ``theta_o_deg``, ``phi_o_deg``, ``value`` (arrays) and ``metadata`` (the ``#gonio`` lines).
    """
    path = Path(path)
    out: dict = {"metadata": {}, "format": None, "theta_i_deg": None, "phi_i_deg": None}
    rows = []
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.startswith("#"):
            text = line[1:].strip()
            if m := re.match(r"format:\s*theta\s+phi\s+(\S+)", text):
                out["format"] = m.group(1).upper()
            elif m := re.match(r"incident_angle\s+(\S+)\s+(\S+)", text):
                out["theta_i_deg"], out["phi_i_deg"] = float(m.group(1)), float(m.group(2))
            elif m := re.match(r"gonio\s+([^:]+):\s*(.*)", text):
                out["metadata"][m.group(1)] = m.group(2)
        elif line.strip():
            rows.append([float(x) for x in line.split()[:3]])
    if out["format"] is None or out["theta_i_deg"] is None:
        raise ValueError(f"pab-opto file {str(path)!r}: needs '#format: theta phi BRDF' and "
                         "'#incident_angle THETA PHI' header lines")
    data = np.asarray(rows, dtype=np.float64).reshape(-1, 3)
    out["theta_o_deg"], out["phi_o_deg"], out["value"] = data[:, 0], data[:, 1], data[:, 2]
    return out
