#!/usr/bin/env bash
# Install everything clnlos needs on a fresh Debian machine (Python >= 3.11, root or sudo):
#   Debian: PoCL (CPU OpenCL), opencl-headers and ocl-icd-opencl-dev (to build pyvkfft),
#   oclgrind (the kernel memory-safety test), mesa-opencl-icd (rusticl on llvmpipe: the second
#   driver stack the stage tests also run on, fp64-less like many GPUs), chromium (optional:
#   the report layout tests and tools/check_report.py look at the study report in it);
#   a virtual environment .venv with the CPU torch wheel first (torch==2.13.0: an unpinned
#   torch would pull a multi-GB CUDA build), pyvkfft built for OpenCL, then clnlos itself.
# Idempotent: what is already there is kept.
set -euo pipefail
cd "$(dirname "$0")/.."

need=()
for pkg in pocl-opencl-icd opencl-headers ocl-icd-opencl-dev oclgrind; do
  dpkg -s "$pkg" >/dev/null 2>&1 || need+=("$pkg")
done
SUDO=""; [ "$(id -u)" = 0 ] || SUDO="sudo"
if [ ${#need[@]} -gt 0 ]; then
  echo "setup: installing Debian packages: ${need[*]}"
  $SUDO apt-get update -q
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -q --no-install-recommends "${need[@]}"
fi
# optional: the second driver stack (tests/test_second_driver.py skips without it)
if ! dpkg -s mesa-opencl-icd >/dev/null 2>&1; then
  echo "setup: installing mesa-opencl-icd (rusticl, optional)"
  { $SUDO apt-get update -q && DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -q \
      --no-install-recommends mesa-opencl-icd; } \
    || echo "setup: warning: mesa-opencl-icd not installed; the rusticl test will skip"
fi
# optional: headless Chromium (tests/test_report_layout.py skips without it)
if ! command -v chromium >/dev/null 2>&1 && ! dpkg -s chromium >/dev/null 2>&1; then
  echo "setup: installing chromium (headless report checks, optional)"
  { $SUDO apt-get update -q && DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -q \
      --no-install-recommends chromium; } \
    || echo "setup: warning: chromium not installed; the report layout test will skip"
fi

PY="${PYTHON:-python3}"
if [ ! -x .venv/bin/python ]; then
  echo "setup: creating .venv with $($PY --version)"
  "$PY" -m venv .venv
fi
pip() { .venv/bin/python -m pip -q --disable-pip-version-check "$@"; }
.venv/bin/python -c "import torch" 2>/dev/null || { echo "setup: torch (CPU)"; pip install torch==2.13.0; }
.venv/bin/python -c "import pyvkfft.opencl" 2>/dev/null || {
  echo "setup: pyvkfft (OpenCL backend, builds from source)"
  VKFFT_BACKEND=opencl pip install "pyvkfft>=2024.1"
}
echo "setup: clnlos"
VKFFT_BACKEND=opencl pip install -e ".[test,ml,vkfft,study]"
# byte-compile the editable sources once: with PYTHONDONTWRITEBYTECODE set (CI images) every
# command would otherwise recompile them (about 0.05 s of each cold start)
.venv/bin/python -m compileall -q clnlos kernels >/dev/null
.venv/bin/clnlos devices
