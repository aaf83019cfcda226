"""Errors that samples share: the dark and white-reference readings that calibrate many samples.

A campaign's f_r of one sample is its net pose signal over K, the white reference's response
interpolated in time, each with the dark interpolated in time subtracted (:mod:`gonio.calibrate`). The
error of a dark or reference reading therefore moves every sample that it calibrates together: the
``stddev`` of brdf.h5 holds it per sample, but not its correlation. Fitting as if samples were
independent then understates the uncertainty of the scale parameters (an albedo is shifted by an error
of the white reference as a whole, however many samples there are).

:func:`shared_errors` recovers that correlated part exactly to first order by running the calibration
itself once per dark and reference reading, with that reading's signal moved by one standard error:
the change of every sample's f_r is one column of U, and the covariance of the samples is
diag(σ² − Σ U²) + U Uᵀ per channel (the channels are calibrated independently).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gonio.calibrate import CalibrationError, calibrate_with_shifts, reference_rho

__all__ = ["shared_errors"]


def shared_errors(folder, value: np.ndarray, rho=None) -> np.ndarray | None:
    """U of shape (N, C, M): the change of each sample's f_r for a one-σ error of each of the M dark
    and reference readings of the campaign in ``folder``, in the sample order of its brdf.h5.

    ``rho``: the white standard's reflectance the brdf.h5 was calibrated with, one number or one per
    channel (:func:`gonio.dataset.calibration_reference` of its attributes); None: what the campaign
    calibrates with, :func:`gonio.calibrate.reference_rho` of the journal's config snapshot and
    detector (which costs the import of gonio.config, 0.15-0.2 s of a ``gonio fit``).

    Returns None when the folder has no journal or its calibration does not reproduce ``value`` (the
    brdf.h5 was made otherwise), so that the caller falls back to independent samples.
    """
    from gonio.store import JOURNAL_NAME, Journal

    try:
        journal = Journal.open(Path(folder) / JOURNAL_NAME, readonly=True)
    except Exception:  # no journal, another format: nothing to say about shared errors
        return None
    try:
        if rho is None:
            try:   # the white standard the campaign was planned with (its config snapshot)
                from gonio.config import parse_config

                snapshot = journal.meta()["config"]
                reference = parse_config(snapshot, f"{folder} (config snapshot)").reference
                rho = reference_rho(reference, journal.detector())[0]
            except Exception:  # a snapshot this gonio cannot read: nothing to say about shared errors
                return None
        measurements = journal.measurements()
    finally:
        journal.close()
    try:
        shifts = calibrate_with_shifts(measurements, rho, expect=value)[1]
    except CalibrationError:  # a standard that does not fit these readings: not what brdf.h5 came from
        return None
    return shifts if shifts is not None and shifts.shape[-1] else None
