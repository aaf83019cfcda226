#!/usr/bin/env bash
# The CUDA checks of gonio's Dr.Jit code, run on a machine with an NVIDIA GPU: the tests that skip without a
# CUDA device (with the default backend resolving to CUDA there, the physics tests of the simulation run
# on CUDA) and the figures of the benchmarks that have a CUDA column. Writes its log to ${OUT:-/tmp}/gpu.log.
#
# The Python packages gonio needs must be importable by `python3` (where they are wheels in .whl/, set
# GONIO_WHEELS=.whl and they are installed into a scratch folder first). gonio is installed (not editable)
# into a scratch folder and the tests run from a copy of tests/, so that the source tree's gonio/ (which
# needs the install's package mapping for gonio.sim and gonio.drivers) does not shadow it.
set -uo pipefail
repo=$(cd "$(dirname "$0")/.." && pwd)
out=${OUT:-/tmp}
log=$out/gpu.log
scratch=$(mktemp -d)
trap 'rm -rf "$scratch"' EXIT
exec > >(tee "$log") 2>&1
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader || true
if [ -n "${GONIO_WHEELS:-}" ]; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
    --target "$scratch/site" "$repo/$GONIO_WHEELS"/*.whl || exit 1
fi
python3 -m pip install -q --no-deps --no-build-isolation --no-compile --no-cache-dir --target "$scratch/gonio" \
  "$repo" || exit 1
export PYTHONPATH="$scratch/gonio:$scratch/site${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1
mkdir -p "$scratch/w" && cp -r "$repo/tests" "$repo/pyproject.toml" "$scratch/w/" && cd "$scratch/w" || exit 1
python3 -c "import sys, drjit as dr, gonio; print(sys.version.split()[0], 'drjit', dr.__version__, 'cuda:',
dr.has_backend(dr.JitBackend.CUDA), gonio.__file__)"
echo "== tests on every backend (CUDA the default where present)"
timeout "${GPU_TEST_TIMEOUT:-240}" python3 -m pytest -q -p no:cacheprovider -rfs --durations=5 -n "${GPU_TEST_WORKERS:-4}" \
  tests/test_jit.py tests/sim tests/test_fit.py tests/test_fit_aperture.py 2>&1 | tail -60
echo "== camera frames"
timeout 120 python3 "$repo/tools/bench_camera.py" --frames 20
for b in llvm cuda; do
  echo "== detector per reading, $b"
  GONIO_BACKEND=$b timeout 120 python3 "$repo/tools/bench_batch.py" --only detector --poses 300
done
for b in llvm cuda; do
  echo "== a whole simulated campaign per step (chunked detector path against one step a unit), $b"
  GONIO_BACKEND=$b timeout 150 python3 "$repo/tools/bench_batch.py" --only campaign --repeats 3 \
    --campaign-grid iso:step=15
done
echo "== float64 accuracy of Dr.Jit operations per backend (max relative error against numpy)"
python3 - <<'PY'
import numpy as np
import drjit as dr
rng = np.random.default_rng(0)
x, y, u = rng.uniform(0.05, 3, 10**5), rng.uniform(-2, 2, 10**5), rng.uniform(-0.99, 0.99, 10**5)
runs = [("llvm", True)] + ([("cuda", True), ("cuda", False)] if dr.has_backend(dr.JitBackend.CUDA) else [])
for be, fast in runs:
    dr.set_flag(dr.JitFlag.FastMath, fast)
    F = __import__(f"drjit.{be}", fromlist=["Float64"]).Float64
    X, Y, U = F(x), F(y), F(u)
    ops = {"rcp": (dr.rcp(X), 1 / x), "rsqrt": (dr.rsqrt(X), 1 / np.sqrt(x)), "1/sqrt": (1 / dr.sqrt(X), 1 / np.sqrt(x)),
           "div": (Y / X, y / x), "exp": (dr.exp(Y), np.exp(y)), "log": (dr.log(X), np.log(x)),
           "power": (dr.power(X, Y), x ** y), "sin": (dr.sin(Y), np.sin(y)), "cos": (dr.cos(Y), np.cos(y)),
           "tan": (dr.tan(U), np.tan(u)), "acos": (dr.acos(U), np.arccos(u)), "atan2": (dr.atan2(Y, X), np.arctan2(y, x)),
           "tanh": (dr.tanh(Y), np.tanh(y))}
    print(f"{be} FastMath={fast}:", ", ".join(f"{k} {np.max(np.abs(a.numpy() - r) / np.abs(r)):.1e}" for k, (a, r) in ops.items()))
PY
echo "== gonio simulate, llvm against cuda"
for b in llvm cuda; do
  /usr/bin/time -f "$b: %e s wall, %U s user" python3 -m gonio.cli simulate "ggx:alpha=0.2,metal=gold" \
    --grid iso:step=10 --seed 1 --backend $b --out "$scratch/sim-$b" 2>&1 | tail -2
done
python3 - "$scratch" <<'PY'
import sys
from pathlib import Path
import h5py
import numpy as np
runs = [Path(sys.argv[1]) / f"sim-{k}" / "brdf.h5" for k in ("llvm", "cuda")]
if all(p.exists() for p in runs):
    (a, sa), (b, sb) = ((np.asarray(h5py.File(p)["samples/value"]), np.asarray(h5py.File(p)["samples/stddev"]))
                        for p in runs)
    z = np.abs(a - b) / np.maximum(np.hypot(sa, sb), 1e-30)
    print(f"samples/value {a.shape}: llvm vs cuda max |difference| / combined stddev {z.max():.3g}, "
          f"max relative {np.max(np.abs(a - b) / np.maximum(np.abs(a), 1e-30)):.3g}")
else:
    print("no llvm/cuda pair to compare:", [str(p) for p in runs if not p.exists()])
PY
