"""The kernel tests again on a second OpenCL driver stack: Mesa's rusticl on llvmpipe (a
different compiler than PoCL, OpenCL 3.0 without cl_khr_fp64, like many GPUs).

Runs the stage test modules in a subprocess with ``CLNLOS_DEVICE=rusticl`` and
``RUSTICL_ENABLE=llvmpipe`` when Debian's ``mesa-opencl-icd`` provides it (tools/setup.sh
installs it); float64 cases skip there with their reason (tests/conftest.py). Skipped when
rusticl is not installed or already the device under test.
"""

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MODULES = ["test_diffusion.py", "test_forward.py", "test_reconstruct.py", "test_stability.py",
           "test_iterative.py"]
ENV = {"CLNLOS_DEVICE": "rusticl", "RUSTICL_ENABLE": "llvmpipe"}


def _rusticl_present() -> bool:
    code = ("import pyopencl as cl, sys\n"
            "sys.exit(0 if any('rusticl' in p.name.lower() and p.get_devices() "
            "for p in cl.get_platforms()) else 1)\n")
    r = subprocess.run([sys.executable, "-c", code], env={**os.environ, **ENV},
                       capture_output=True, timeout=120)
    return r.returncode == 0


@pytest.mark.slow
def test_stage_tests_pass_on_rusticl():
    if os.environ.get("CLNLOS_DEVICE", "").lower().startswith("rusticl"):
        pytest.skip("already running on rusticl")
    if not _rusticl_present():
        pytest.skip("Mesa rusticl (mesa-opencl-icd with RUSTICL_ENABLE=llvmpipe) not installed")
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                        "-m", "not shared_data", "--tb=short",
                        *(str(ROOT / "tests" / m) for m in MODULES)],
                       env={**os.environ, **ENV}, capture_output=True, text=True, cwd=ROOT,
                       timeout=1800)
    tail = (r.stdout + r.stderr)[-6000:]
    assert r.returncode == 0, tail
    assert " passed" in r.stdout and "failed" not in r.stdout.splitlines()[-1], tail
