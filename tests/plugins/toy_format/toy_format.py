"""A toy export format (docs/EXTENDING.md, "A new export format"): the measured samples as JSON lines,
one object per sample. The whole plugin is this file; ``GONIO_PLUGINS=toy_format`` loads it."""

import json

import numpy as np

from gonio.export import ExportReport
from gonio.registries import EXPORT_FORMATS


@EXPORT_FORMATS.register("jsonl", "the measured samples as JSON lines, one object per sample",
                         file_name="brdf.samples.jsonl")
def export_jsonl(job, out):
    data = job.data  # the samples, read from the campaign folder or brdf.h5 on first use
    angles = np.stack([np.ravel(a) for a in (data.theta_i, data.phi_i, data.theta_o, data.phi_o)], axis=1)
    values = np.asarray(data.value, dtype=float).reshape(len(angles), -1)
    with open(out, "w") as f:
        for (ti, pi, to, po), v in zip(angles.tolist(), values.tolist(), strict=True):
            f.write(json.dumps({"theta_i": ti, "phi_i": pi, "theta_o": to, "phi_o": po, "f_r": v}) + "\n")
    finite = int(np.isfinite(values).all(axis=1).sum())
    return ExportReport(job.format, [out], len(angles), finite, 0, len(angles) - finite,
                        notes=["one JSON object per measured sample; angles in degrees, f_r in sr^-1"])
