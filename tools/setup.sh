#!/usr/bin/env bash
# Set-up for a fresh Debian/Ubuntu machine: libLLVM 19 for Dr.Jit, a virtual environment, the packages.
set -euo pipefail
venv=${1:-.venv}

have_llvm19() { ldconfig -p 2>/dev/null | grep -q 'libLLVM.so.19' || ls /usr/lib/*/libLLVM*.so.19* >/dev/null 2>&1; }

# Dr.Jit's LLVM backend loads the newest libLLVM it finds; Debian 12's LLVM 15 aborts on dr.minimum/maximum.
if ! have_llvm19; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    (apt-get install -y -q libllvm19 >/dev/null 2>&1 || { apt-get update -q >/dev/null && apt-get install -y -q libllvm19 >/dev/null; }) \
      || echo "gonio setup: could not install libllvm19; run: sudo apt-get install -y libllvm19" >&2
  elif command -v sudo >/dev/null && sudo -n true 2>/dev/null; then
    sudo apt-get install -y -q libllvm19 >/dev/null || echo "gonio setup: run: sudo apt-get install -y libllvm19" >&2
  else
    echo "gonio setup: Dr.Jit needs LLVM 19 and it is missing; run: sudo apt-get install -y libllvm19" >&2
  fi
fi

# The daemon's web view is tested in a real headless browser: Debian's chromium (Playwright drives it;
# never `playwright install`). Without it those tests are skipped.
if ! command -v chromium >/dev/null; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    (apt-get install -y -q chromium >/dev/null 2>&1 || { apt-get update -q >/dev/null && apt-get install -y -q chromium >/dev/null; }) \
      || echo "gonio setup: could not install chromium (web view tests are skipped); run: sudo apt-get install -y chromium" >&2
  elif command -v sudo >/dev/null && sudo -n true 2>/dev/null; then
    sudo apt-get install -y -q chromium >/dev/null || echo "gonio setup: run: sudo apt-get install -y chromium" >&2
  else
    echo "gonio setup: chromium is missing (the web view tests are skipped); run: sudo apt-get install -y chromium" >&2
  fi
fi

[ -x "$venv/bin/python" ] || python3 -m venv "$venv"
"$venv/bin/python" -m pip install -q --upgrade pip
"$venv/bin/python" -m pip install -q -e '.[dev]'
