"""The Dr.Jit backend choice: argument, config, GONIO_BACKEND, CUDA when present; refusals in one line."""

from __future__ import annotations

import drjit as dr
import pytest
from cli_helpers import one_clear_line

from gonio.campaign import open_campaign
from gonio.cli import main
from gonio.config import ConfigError, load_config, parse_config, with_sim_detector
from gonio.jit import (
    BACKENDS,
    ENV_VAR,
    array_types,
    backend_of,
    cuda_available,
    resolve_backend,
    using_backend,
)
from gonio.sim.gantry import SimGantry

CUDA = cuda_available()
no_cuda = pytest.mark.skipif(CUDA, reason="a CUDA device is present: asking for cuda is not refused here")


def test_the_default_is_cuda_when_present_else_llvm(monkeypatch):
    monkeypatch.delenv(ENV_VAR, raising=False)
    assert resolve_backend() == ("cuda" if CUDA else "llvm")
    assert CUDA == dr.has_backend(dr.JitBackend.CUDA)


def test_the_environment_picks_the_backend_and_an_argument_overrides_it(monkeypatch):
    monkeypatch.setenv(ENV_VAR, " LLVM ")
    assert resolve_backend() == "llvm"
    monkeypatch.setenv(ENV_VAR, "metal")
    with pytest.raises(ValueError, match=f"^{ENV_VAR}: 'metal' is not one of llvm, cuda$"):
        resolve_backend()
    assert resolve_backend("llvm") == "llvm"  # what the caller names wins over the environment
    with pytest.raises(ValueError, match="^backend: 'vulkan' is not one of llvm, cuda$"):
        resolve_backend("vulkan")


@no_cuda
def test_cuda_without_a_device_is_refused(monkeypatch):
    with pytest.raises(ValueError, match="no CUDA device"):
        resolve_backend("cuda")
    monkeypatch.setenv(ENV_VAR, "cuda")
    with pytest.raises(ValueError, match=f"^{ENV_VAR}: 'cuda' asked for"):
        resolve_backend()


@pytest.mark.parametrize("name", BACKENDS)
def test_array_types_are_those_of_the_backend(name):
    t = array_types(name)
    assert t.__name__ == f"drjit.{name}" and array_types(name, ad=True).__name__ == f"drjit.{name}.ad"
    if name == "llvm" or CUDA:
        assert backend_of(t.Array3f(1, 2, 3)) == name


def test_the_config_field_chooses_the_simulated_detectors_backend(backend):
    data = load_config().model_dump()
    data["detector"]["sim"]["backend"] = backend
    for kind in ("photodiode", "spectrometer", "camera"):
        g = SimGantry.from_config(with_sim_detector(parse_config(data), kind), "lambert:albedo=0.5", seed=1)
        assert g.detector.backend == backend
    data["detector"]["sim"]["backend"] = "opencl"
    with pytest.raises(ConfigError, match="detector.sim.backend"):
        parse_config(data)


def test_gonio_simulate_and_fit_take_backend(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv(ENV_VAR, "metal")  # --backend wins over the environment
    out = tmp_path / "c"
    assert main(["simulate", "lambert:albedo=0.5", "--grid", "iso:step=45", "--out", str(out), "--quiet",
                 "--backend", "llvm"]) == 0
    assert main(["fit", str(out), "--model", "lambert", "--backend", "llvm", "--quiet"]) == 0
    assert capsys.readouterr().out.startswith("lambert:albedo=0.5")
    c = open_campaign(out)
    try:  # every simulated reading says which backend rendered it
        assert {m.extra["backend"] for m in c.journal.measurements()} == {"llvm"}
    finally:
        c.close()


def test_a_command_chooses_the_backend_for_all_it_runs_until_it_ends(monkeypatch):
    monkeypatch.delenv(ENV_VAR, raising=False)
    default = resolve_backend()
    with using_backend("llvm") as name:
        assert name == "llvm" and resolve_backend() == "llvm"
        with using_backend(None):
            assert resolve_backend() == "llvm"
    assert resolve_backend() == default


@no_cuda
def test_gonio_simulate_and_fit_refuse_cuda_without_a_device_before_writing(tmp_path, capsys, monkeypatch):
    out = tmp_path / "c"
    assert main(["simulate", "lambert:albedo=0.5", "--grid", "iso:step=45", "--out", str(out), "--quiet",
                 "--backend", "cuda"]) == 2
    one_clear_line(capsys, "no CUDA device")
    assert not out.exists()
    monkeypatch.setenv(ENV_VAR, "cuda")
    simulate = ["simulate", "lambert:albedo=0.5", "--grid", "iso:step=45", "--out", str(out), "--quiet"]
    assert main(simulate) == 2
    one_clear_line(capsys, ENV_VAR, "no CUDA device")
    assert not out.exists()
    monkeypatch.setenv(ENV_VAR, "llvm")
    assert main(simulate) == 0
    capsys.readouterr()
    assert main(["fit", str(out), "--model", "lambert", "--backend", "cuda"]) == 2
    one_clear_line(capsys, "no CUDA device")


def test_exact_float64_turns_fast_math_off_for_float64_inside_the_block_only():
    """Dr.Jit's fast math makes CUDA's float64 reciprocals approximate (1e-6): float64 work is traced
    with it off, float32 (the simulation path) keeps it, and the flag comes back after the block."""
    from drjit.llvm import Array3f, Array3f64, Float64

    from gonio.jit import exact_float64

    assert dr.flag(dr.JitFlag.FastMath)
    with exact_float64(Float64):
        assert not dr.flag(dr.JitFlag.FastMath)
    with exact_float64(Array3f64(1, 2, 3)):
        assert not dr.flag(dr.JitFlag.FastMath)
    with exact_float64(Array3f):
        assert dr.flag(dr.JitFlag.FastMath)
    assert dr.flag(dr.JitFlag.FastMath)
