"""Fixtures shared across the test folders."""

import pytest
from brdf_samples import sampled
from jit_backends import backend_params

from gonio.jit import ENV_VAR, array_types


@pytest.fixture
def make_sampled():
    """``sampled(spec, grid, theta_max_deg=85, rel_sd=0.01)``: a SampledBRDF from a material's own eval."""
    return sampled


@pytest.fixture(params=backend_params())
def backend(request, monkeypatch):
    """Each Dr.Jit backend in turn (CUDA skipped where Dr.Jit finds no device). ``GONIO_BACKEND`` is set to
    it for the test, so everything that resolves the default backend (simulated detectors, fits,
    materials evaluated from numpy, subprocesses) computes there."""
    monkeypatch.setenv(ENV_VAR, request.param)
    return request.param


@pytest.fixture
def jit(backend):
    """The Dr.Jit array types of each backend in turn (``jit.Float64``, ``jit.Array3f``, ``jit.PCG32``...)."""
    return array_types(backend)
