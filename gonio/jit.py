"""Which Dr.Jit backend the physics runs on: LLVM (the CPU) or CUDA (an NVIDIA GPU).

One choice for the whole process, resolved once per object that computes (a simulated detector, a fit, a
material evaluated from numpy), in this order:

1. what the caller names: the config's ``[detector.sim] backend`` (for the simulated detector), or a
   ``backend=`` argument;
2. the backend a command chose for everything it runs (:func:`using_backend`: ``gonio simulate
   --backend``, ``gonio fit --backend``);
3. the environment variable ``GONIO_BACKEND`` (``llvm`` or ``cuda``);
4. CUDA when Dr.Jit finds a CUDA device, else LLVM.

Asking for CUDA where there is no device is refused in one line; so is a name that is not a backend.
The code that computes derives its array types from this name (:func:`array_types`) or from its
inputs, never from a hard-wired ``drjit.llvm``: the same functions run on both backends. Results are
bit-identical run to run on one backend, not between backends (float32 transcendental functions and
divisions round differently on the GPU).

This module imports nothing heavy: Dr.Jit is imported when a backend is resolved.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["BACKENDS", "ENV_VAR", "resolve_backend", "using_backend", "cuda_available", "array_types",
           "backend_of", "upload", "exact_float64"]

#: The Dr.Jit backends gonio computes on.
BACKENDS = ("llvm", "cuda")
#: The environment variable that picks the backend when the caller does not.
ENV_VAR = "GONIO_BACKEND"
#: The backend a command chose for everything it runs (:func:`using_backend`); None: not chosen.
_chosen: str | None = None


def cuda_available() -> bool:
    """True when Dr.Jit finds a CUDA device (the driver loads and a GPU is present)."""
    import drjit as dr

    return bool(dr.has_backend(dr.JitBackend.CUDA))


def resolve_backend(backend: str | None = None) -> str:
    """The backend to compute on: ``backend`` if given, else the one :func:`using_backend` chose, else
    ``$GONIO_BACKEND``, else CUDA when present.

    Parameters
    ----------
    backend : {"llvm", "cuda"}, optional
        The caller's choice (a config field, an argument); None: not chosen.

    Returns
    -------
    str
        ``"llvm"`` or ``"cuda"``.

    Raises
    ------
    ValueError
        A name that is not one of :data:`BACKENDS` (naming where it came from), or ``cuda`` on a machine
        where Dr.Jit finds no CUDA device.
    """
    source = "backend"
    if backend is None and _chosen is not None:
        return _chosen
    if backend is None:
        env = os.environ.get(ENV_VAR, "").strip()
        if not env:
            return "cuda" if cuda_available() else "llvm"
        backend, source = env.lower(), ENV_VAR
    if backend not in BACKENDS:
        raise ValueError(f"{source}: {backend!r} is not one of {', '.join(BACKENDS)}")
    if backend == "cuda" and not cuda_available():
        raise ValueError(f"{source}: 'cuda' asked for, but Dr.Jit finds no CUDA device (use llvm)")
    return backend


@contextmanager
def exact_float64(kind) -> Iterator[None]:
    """Trace float64 arithmetic with correctly rounded reciprocals on every backend, until the block ends.

    Dr.Jit's fast-math flag (on by default) makes the CUDA backend compute reciprocals with the GPU's
    approximate ``rcp.approx.ftz`` instruction, for float64 too; ``dr.rcp``, ``dr.rsqrt``,
    ``dr.normalize``, a 3-vector divided by a scalar array and a negative integer power all go through
    it. That is a relative error of 1e-6 where float64 promises 1e-16 (measured on an H200 by
    ``tools/gpu_check.sh``): the float64 reference path and the fits would be no better than float32
    there. For ``kind`` (a Dr.Jit array or array type) of float64 this block turns the flag off; the flag
    is per thread, so each call that traces sets it itself. On LLVM float64 reciprocals are divisions
    either way (results unchanged), and float32, the simulation's path, keeps Dr.Jit's defaults.
    """
    import drjit as dr

    if dr.type_v(kind) == dr.VarType.Float64:
        with dr.scoped_set_flag(dr.JitFlag.FastMath, False):
            yield
    else:
        yield


@contextmanager
def using_backend(backend: str | None) -> Iterator[str]:
    """Compute on ``backend`` (resolved and checked now) wherever nothing names another, until the block
    ends: what ``--backend`` of a command does. None: the block resolves as before. Yields the name."""
    global _chosen
    name = resolve_backend(backend)
    before = _chosen
    if backend is not None:
        _chosen = name
    try:
        yield name
    finally:
        _chosen = before


def array_types(backend: str, ad: bool = False):
    """The Dr.Jit module of array types of ``backend``: ``drjit.llvm`` or ``drjit.cuda`` (their ``.ad``
    variants with ``ad=True``), e.g. ``array_types("llvm").Array3f``."""
    if backend not in BACKENDS:
        raise ValueError(f"backend: {backend!r} is not one of {', '.join(BACKENDS)}")
    if backend == "cuda":
        import drjit.cuda as plain
        import drjit.cuda.ad as diff
    else:
        import drjit.llvm as plain
        import drjit.llvm.ad as diff
    return diff if ad else plain


def backend_of(value) -> str:
    """The backend name of a Dr.Jit array (or 3-vector) ``value``."""
    import drjit as dr

    return "cuda" if dr.backend_v(value) == dr.JitBackend.CUDA else "llvm"


def upload(cls, values, dtype):
    """A Dr.Jit array of type ``cls`` holding ``values`` (1-D, converted to the numpy ``dtype``), from a
    64-byte aligned copy.

    Dr.Jit maps numpy memory as it finds it and compiles loads for that alignment, so inputs of varying
    alignment would compile a new kernel on every call; aligned buffers keep one kernel.
    """
    import numpy as np

    v = np.asarray(values, dtype=dtype).reshape(-1)
    itemsize = v.dtype.itemsize
    buffer = np.empty(v.size + 64 // itemsize, dtype=v.dtype)
    start = (-buffer.ctypes.data % 64) // itemsize
    out = buffer[start:start + v.size]
    out[:] = v
    return cls(out)
