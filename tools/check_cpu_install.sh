#!/usr/bin/env bash
# The install route without root: a fresh virtual environment, `pip install ".[cpu]"` (PoCL
# from PyPI: pocl-binary-distribution puts its ICD file beside the loader pyopencl's wheels
# bundle), then, with the system's OpenCL drivers hidden (OCL_ICD_VENDORS names only that
# folder: a machine without root-installed OpenCL), `clnlos devices`, a simulation and an
# LCT reconstruction; the same capture reconstructed on the system's first device, when there
# is one, for comparison. Needs the package index.
#   bash tools/check_cpu_install.sh [VENV_DIR]   (default: a temporary folder, removed after)
set -euo pipefail
cd "$(dirname "$0")/.."
TMP="$(mktemp -d)"
VENV="${1:-$TMP/venv}"
"${PYTHON:-python3}" -m venv "$VENV"
"$VENV/bin/pip" -q install ".[cpu]"
WHEEL_ICD="$("$VENV/bin/python" -c \
  "import pathlib, pyopencl; print(pathlib.Path(pyopencl.__file__).parent / '.libs')")"
cd "$TMP"
OCL_ICD_VENDORS="$WHEEL_ICD" "$VENV/bin/clnlos" devices
OCL_ICD_VENDORS="$WHEEL_ICD" "$VENV/bin/python" - <<'PY'
import numpy as np

import clnlos

scene = {"scan": {"width_m": 0.3, "points": 8}, "time": {"bin_width_s": 2e-11, "bins": 128},
         "objects": [{"shape": "rectangle", "size_m": [0.1, 0.1], "translate_m": [0, 0, 0.25]}],
         "slab": {"thickness_m": 0.0254, "mu_a": 0.53, "mu_s_prime": 262.0, "n": 1.12},
         "detector": {"power_w": 0.4, "exposure_s": 0.5}}
capture = clnlos.simulate(scene)
rec = clnlos.reconstruct(capture, method="lct")
np.save("transient.npy", capture.transient)
np.save("volume.npy", rec.volume)
print(f"PoCL from PyPI: volume {rec.volume.shape} [z, y, x], max {rec.volume.max():.3g}")
PY
"$VENV/bin/python" - <<'PY' || echo "no system OpenCL device to compare with"
import numpy as np

import clnlos
from clnlos.io.capture import Capture

tau = np.load("transient.npy")
slab = '{"thickness_m": 0.0254, "mu_a": 0.53, "mu_s_prime": 262.0, "n": 1.12}'
capture = Capture(tau, 2e-11, 0.0, 0.3, "transient.npy", {"slab": slab})
ref = clnlos.reconstruct(capture, method="lct", device="0:0").volume
vol = np.load("volume.npy")
print(f"system device 0:0: max relative difference {np.abs(vol - ref).max() / ref.max():.2e}")
PY
cd / && rm -rf "$TMP"
