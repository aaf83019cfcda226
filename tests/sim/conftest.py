"""Fixtures for the simulation tests: the numpy reference on sys.path, seeded RNGs, Dr.Jit backends."""

from __future__ import annotations

import os
import sys

import drjit as dr
import numpy as np
import pytest

# The numpy reference (materials_ref.py) is a plain module beside the tests, not a package.
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))


@pytest.fixture
def rng():
    """A numpy generator with a fixed seed: every test sees the same directions on every run."""
    return np.random.default_rng(20240611)


def _vector_types():
    from drjit.llvm import Array3f, Array3f64

    params = [pytest.param(Array3f, id="llvm-float32"), pytest.param(Array3f64, id="llvm-float64")]
    cuda = dr.has_backend(dr.JitBackend.CUDA)
    if cuda:
        from drjit.cuda import Array3f as CudaArray3f

        params.append(pytest.param(CudaArray3f, id="cuda-float32"))
    else:
        params.append(pytest.param(None, id="cuda-float32",
                                   marks=pytest.mark.skip(reason="no CUDA device")))
    return params


@pytest.fixture(params=_vector_types())
def vector_type(request):
    """Each Dr.Jit 3-vector type a material must run on (CUDA skipped when absent)."""
    return request.param


def _to_dr(vector_type, w):
    scalar = dr.value_t(vector_type)
    dtype = np.float64 if dr.type_v(scalar) == dr.VarType.Float64 else np.float32
    return vector_type(*(scalar(np.ascontiguousarray(w[:, j], dtype=dtype)) for j in range(3)))


@pytest.fixture
def to_dr():
    """``to_dr(vector_type, w)``: numpy (N, 3) → a Dr.Jit 3-vector of that type and precision."""
    return _to_dr
