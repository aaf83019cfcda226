"""The Dr.Jit backends a physics test runs on: every backend of :data:`gonio.jit.BACKENDS`, CUDA skipped
where Dr.Jit finds no device (so the same tests run unchanged on a machine with a GPU)."""

import drjit as dr
import pytest

from gonio.jit import BACKENDS


def backend_params() -> list:
    """One pytest param per backend, id the backend's name; CUDA marked skip without a device."""
    cuda = bool(dr.has_backend(dr.JitBackend.CUDA))
    return [pytest.param(b, id=b, marks=() if b != "cuda" or cuda else
                         pytest.mark.skip(reason="no CUDA device")) for b in BACKENDS]
