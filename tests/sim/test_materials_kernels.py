"""The Dr.Jit entry point: type-generic over backends and precisions, and one compiled kernel per model
configuration, reused across batches, batch sizes and parameter values."""

from __future__ import annotations

import drjit as dr
import materials_ref as ref
import numpy as np
import pytest

from gonio.sim.materials import load

SPECS = [
    "lambert:albedo=0.8/0.6/0.4",
    "phong:ks=0.5,ke=20",
    "modified-phong:ks=0.5,ke=20",
    "blinn-phong:ks=0.5,ke=20",
    "normalized-blinn-phong:ks=0.5,ke=20",
    "ward:rho_s=0.2,alpha_x=0.1,alpha_y=0.3",
    "cook-torrance:d=beckmann,m=0.2,metal=gold",
    "cook-torrance:d=blinn,m=0.2,fresnel=dielectric,eta=1.5",
    "cook-torrance:d=gaussian,m=0.2,fresnel=none",
    "ggx:alpha=0.2,metal=gold",
    "ggx:alpha=0.2,metal=gold,smith=correlated",
]


@pytest.mark.parametrize("spec", SPECS)
def test_eval_dr_follows_the_input_type(spec, vector_type, to_dr):
    m = load(spec)
    wi, wo = ref.random_pairs(np.random.default_rng(4), 257)
    out = m.eval_dr(to_dr(vector_type, wi), to_dr(vector_type, wo))
    assert type(out) is vector_type and dr.width(out) == 257
    values = np.stack([c.numpy() for c in (out.x, out.y, out.z)], axis=1)
    np.testing.assert_allclose(values, m.eval(wi, wo, precision="float64"), rtol=2e-4, atol=1e-30)


def _jit_kernels(run):
    with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
        dr.kernel_history_clear()
        run()
        return [k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]


def _directions(n, seed, jit):
    """Directions made in Dr.Jit and evaluated (otherwise their generation, seed included, would be
    fused into the BRDF kernel, and that part belongs to the caller)."""
    rng = jit.PCG32(size=n, initstate=seed)
    z = rng.next_float32() * 0.99 + 0.01
    phi = rng.next_float32() * 6.283185
    r = dr.sqrt(1 - z * z)
    w = jit.Array3f(r * dr.cos(phi), r * dr.sin(phi), z)
    dr.eval(w)
    return w


@pytest.mark.parametrize("family", [
    ["cook-torrance:d=beckmann,m=0.2,metal=gold", "cook-torrance:d=beckmann,m=0.35,metal=copper,rho_d=0.1",
     "cook-torrance:d=beckmann,m=0.05,fresnel=conductor,eta=0.2/0.9/1.1,k=3.9/2.4/2.2,denom=4,rho_s=0.8"],
    ["ggx:alpha=0.2,metal=gold", "ggx:alpha_u=0.1,alpha_v=0.4,metal=steel,rho_d=0.2,rho_s=0.7"],
    ["ward:rho_s=0.2,alpha=0.1", "ward:rho_d=0.3,rho_s=0.05,alpha_x=0.4,alpha_y=0.1"],
    ["modified-phong:ks=0.5,ke=20", "modified-phong:ks=0.2/0.3/0.4,ke=3.5,rho_d=0.5"],
    ["cook-torrance:d=gaussian,m=0.2,fresnel=none", "cook-torrance:d=gaussian,m=0.9,fresnel=none,denom=4"],
])
def test_one_kernel_per_configuration(family, jit):
    """After a first call, new directions, batch sizes and parameter values reuse the compiled kernel
    (parameters are opaque), on both the Dr.Jit path and the numpy path."""
    materials = [load(spec) for spec in family]
    wi_np, wo_np = ref.random_pairs(np.random.default_rng(6), 3000)

    def warm():
        dr.eval(materials[0].eval_dr(_directions(1000, 1, jit), _directions(1000, 2, jit)))
        materials[0].eval(wi_np[:1000], wo_np[:1000])

    _jit_kernels(warm)
    later = []
    for i, m in enumerate(materials):
        n = 1500 + 700 * i
        wi, wo = _directions(n, 10 + i, jit), _directions(n, 20 + i, jit)
        later += _jit_kernels(lambda m=m, wi=wi, wo=wo: dr.eval(m.eval_dr(wi, wo)))
        later += _jit_kernels(lambda m=m, n=n: m.eval(wi_np[:n], wo_np[:n]))
    assert len(later) == 2 * len(materials)  # one kernel per call, nothing else compiled
    assert all(k["cache_hit"] for k in later)
    assert len({k["hash"] for k in later}) == 1


@pytest.fixture(scope="module")
def tensor_file(tmp_path_factory):
    from brdf_samples import tiny_tensor_file

    return tiny_tensor_file(tmp_path_factory.mktemp("bsdf") / "tiny.bsdf")


@pytest.mark.parametrize("spec", SPECS + ["bsdf:{tensor}"])
def test_evaluate_replays_the_traced_kernel_bit_for_bit(spec, vector_type, to_dr, tensor_file):
    """The frozen path (after its first, recording call) gives what eval_dr gives, for every model,
    batch size (one direction is a special case for a recording) and precision."""
    m = load(spec.format(tensor=tensor_file))
    rng = np.random.default_rng(8)
    for n in (40, 1, 257, 1, 3000):
        wi, wo = (to_dr(vector_type, w) for w in ref.random_pairs(rng, n))
        want = m.eval_dr(wi, wo)
        got = m.evaluate(wi, wo)
        assert type(got) is vector_type and dr.width(got) == n
        for c in range(3):
            np.testing.assert_array_equal(np.asarray(got[c]), np.asarray(want[c]))


def test_evaluate_after_its_first_call_traces_nothing(jit):
    """A replay launches the recorded kernel: the same kernel as eval_dr's (one hash, a cache hit),
    whatever the number of directions."""
    m = load("ggx:alpha=0.2,metal=gold")
    m.evaluate(_directions(500, 1, jit), _directions(500, 2, jit))
    wi, wo = _directions(800, 3, jit), _directions(800, 4, jit)
    traced = _jit_kernels(lambda: dr.eval(m.eval_dr(wi, wo)))
    later = []
    for n in (700, 5000):
        wi, wo = _directions(n, 10 + n, jit), _directions(n, 20 + n, jit)
        later += _jit_kernels(lambda wi=wi, wo=wo: m.evaluate(wi, wo))
    assert len(later) == 2 and {k["hash"] for k in later} == {k["hash"] for k in traced}
    assert all(k["cache_hit"] for k in later)


def test_evaluate_from_several_threads_gives_each_its_own_values(jit):
    """The daemon evaluates materials on request threads: calls of one material from several threads at
    once each get the values of their own directions."""
    import threading

    m = load("cook-torrance:d=beckmann,m=0.2,metal=gold")
    sizes = [300, 350, 400, 450]
    inputs = [(_directions(n, 30 + k, jit), _directions(n, 60 + k, jit)) for k, n in enumerate(sizes)]
    want = [np.stack([np.asarray(c) for c in m.eval_dr(wi, wo)], axis=1) for wi, wo in inputs]
    got, errors = [None] * 4, []

    def work(k):
        try:
            for _ in range(10):
                got[k] = np.stack([np.asarray(c) for c in m.evaluate(*inputs[k])], axis=1)
        except Exception as exc:  # noqa: BLE001 - reported below
            errors.append(exc)

    threads = [threading.Thread(target=work, args=(k,)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=60)
    assert not errors and not any(t.is_alive() for t in threads)
    for g, w in zip(got, want, strict=True):
        np.testing.assert_array_equal(g, w)
