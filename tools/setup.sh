#!/usr/bin/env bash
# Set-up for a fresh Debian/Ubuntu machine, in two sizes:
#   tools/setup.sh VENV runtime   libLLVM 19 for Dr.Jit, a virtual environment, gonio and its runtime
#                                 dependencies (what `make demo` needs);
#   tools/setup.sh VENV dev       the same, plus the development extras (pytest, Mitsuba, pyradiance,
#                                 Playwright, schemathesis, xarray, ...) and Debian's chromium (`make test`).
set -euo pipefail
venv=${1:-.venv}
what=${2:-dev}
case "$what" in runtime|dev) ;; *) echo "gonio setup: the second argument is runtime or dev, got '$what'" >&2; exit 2;; esac
export PIP_DISABLE_PIP_VERSION_CHECK=1

# apt_install PACKAGE WHY: installed quietly as root or through password-less sudo; otherwise one line
# says what to run.
apt_install() {
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    (apt-get install -y -q "$1" >/dev/null 2>&1 || { apt-get update -q >/dev/null && apt-get install -y -q "$1" >/dev/null; }) \
      || echo "gonio setup: could not install $1 ($2); run: sudo apt-get install -y $1" >&2
  elif command -v sudo >/dev/null && sudo -n true 2>/dev/null; then
    sudo apt-get install -y -q "$1" >/dev/null 2>&1 || echo "gonio setup: run: sudo apt-get install -y $1 ($2)" >&2
  else
    echo "gonio setup: $1 is missing ($2); run: sudo apt-get install -y $1" >&2
  fi
}

have_llvm19() { ldconfig -p 2>/dev/null | grep -q 'libLLVM.so.19' || ls /usr/lib/*/libLLVM*.so.19* >/dev/null 2>&1; }

# Dr.Jit's LLVM backend loads the newest libLLVM it finds; Debian 12's LLVM 15 aborts on dr.minimum/maximum.
have_llvm19 || apt_install libllvm19 "Dr.Jit's LLVM backend needs LLVM 19"

# The web view's and the report's browser tests drive Debian's chromium (Playwright drives it; never
# `playwright install`). Without it those tests are skipped. Only the tests need it.
if [ "$what" = dev ] && ! command -v chromium >/dev/null; then
  apt_install chromium "the browser tests are skipped without it"
fi

[ -x "$venv/bin/python" ] || python3 -m venv "$venv"
# Editable installs of a pyproject.toml project need pip >= 21.3 (Debian 12 ships 23.0).
"$venv/bin/python" -c 'import sys, pip; sys.exit(tuple(map(int, pip.__version__.split(".")[:2])) < (21, 3))' \
  || "$venv/bin/python" -m pip install -q --upgrade pip
# --no-compile: Python compiles what it imports when it first imports it, not every module of scipy,
# scikit-image and colour-science up front.
spec=.
[ "$what" = dev ] && spec='.[dev]'
# uv (Astral's installer, fetched by pip into the venv) installs the ~150 packages in about 10 s where pip
# takes about 40 s. It reads no pip.conf, so it is given pip's own sources (index, extra indexes,
# find-links, constraints: `pip config list`, environment included) and pip's way of choosing among them
# (the best match over every index). Where uv cannot be fetched or fails, pip installs as before.
# GONIO_NO_UV=1: pip.
uv_sources() {
  "$venv/bin/python" - <<'PY'
import subprocess, sys
out = subprocess.run([sys.executable, "-m", "pip", "config", "list"], capture_output=True, text=True).stdout
rank, found = {"global": 0, "user": 1, "site": 2, ":env:": 3}, {}
for line in out.splitlines():
    key, _, value = line.partition("=")
    scope, _, name = key.rpartition(".")
    r = rank.get(scope, 0)
    if name in ("index-url", "extra-index-url", "find-links", "constraint") and r >= found.get(name, (-1,))[0]:
        found[name] = (r, value.strip().strip("'\""))
print("--index-strategy\nunsafe-best-match")
for name, (_, value) in found.items():
    for v in value.split():
        print(f"--{name}\n{v}")
PY
}
if [ -n "${GONIO_NO_UV:-}" ] || ! { "$venv/bin/python" -m pip install -q uv >/dev/null 2>&1 \
    && mapfile -t sources < <(uv_sources) \
    && "$venv/bin/python" -m uv pip install -q --python "$venv/bin/python" "${sources[@]}" -e "$spec"; }; then
  [ -n "${GONIO_NO_UV:-}" ] || echo "gonio setup: uv could not install; pip installs instead" >&2
  "$venv/bin/python" -m pip install -q --no-compile -e "$spec"
fi
