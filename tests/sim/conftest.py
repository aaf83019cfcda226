"""Fixtures for the simulation tests: the numpy reference on sys.path, seeded RNGs, Dr.Jit backends."""

from __future__ import annotations

import os
import sys

import drjit as dr
import numpy as np
import pytest
from jit_backends import backend_params

from gonio.jit import array_types

# The numpy reference (materials_ref.py) is a plain module beside the tests, not a package.
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))


@pytest.fixture
def rng():
    """A numpy generator with a fixed seed: every test sees the same directions on every run."""
    return np.random.default_rng(20240611)


def _vector_types():
    """Array3f and Array3f64 of every backend (CUDA skipped without a device)."""
    params = []
    for backend in backend_params():
        name = backend.values[0]
        for precision, attr in (("float32", "Array3f"), ("float64", "Array3f64")):
            params.append(pytest.param((name, attr), id=f"{name}-{precision}", marks=backend.marks))
    return params


@pytest.fixture(params=_vector_types())
def vector_type(request):
    """Each Dr.Jit 3-vector type a material must run on (CUDA skipped when absent)."""
    backend, attr = request.param
    return getattr(array_types(backend), attr)


def _to_dr(vector_type, w):
    scalar = dr.value_t(vector_type)
    dtype = np.float64 if dr.type_v(scalar) == dr.VarType.Float64 else np.float32
    return vector_type(*(scalar(np.ascontiguousarray(w[:, j], dtype=dtype)) for j in range(3)))


@pytest.fixture
def to_dr():
    """``to_dr(vector_type, w)``: numpy (N, 3) → a Dr.Jit 3-vector of that type and precision."""
    return _to_dr
