"""Kernel memory safety: every kernel family under Oclgrind. Out-of-bounds accesses and data
races fail the test. Runs where Oclgrind is installed (tools/setup.sh installs Debian's
oclgrind, so CI runs it); skipped elsewhere.

Uninitialised-value tracking is not asserted yet: Oclgrind 21.10 reports reads of
clEnqueueFillBuffer memory as uninitialised (worked around in runtime.fill_zero), reports
every read_imagef result as uninitialised, and flags transmittance_outer after a buffer of
another size was freed, which a minimal reproduction of the same pattern does not show; this
is left for the stability issue.
"""

import os
import subprocess
import sys
from pathlib import Path

import pytest

ICD = Path("/usr/lib/oclgrind/liboclgrind-rt-icd.so")
KERNEL_ERRORS = ("Invalid read", "Invalid write", "Data race", "data race",
                 "Work-group divergence", "Invalid access", "out of bounds")


@pytest.mark.oclgrind
def test_all_kernels_clean_under_oclgrind(tmp_path):
    if not ICD.is_file():
        pytest.skip("Oclgrind not installed (Debian package oclgrind)")
    (tmp_path / "oclgrind.icd").write_text(str(ICD) + "\n")
    env = dict(os.environ, OCL_ICD_VENDORS=str(tmp_path), CLNLOS_FFT="host",
               OCLGRIND_DATA_RACES="1", CLNLOS_DEVICE="oclgrind")
    driver = Path(__file__).with_name("memcheck_driver.py")
    r = subprocess.run([sys.executable, str(driver)], capture_output=True, text=True, env=env,
                       timeout=900, cwd=tmp_path)
    log = r.stdout + r.stderr
    assert r.returncode == 0, log[-4000:]
    assert "MEMCHECK DONE" in r.stdout
    found = [e for e in KERNEL_ERRORS if e in log]
    assert not found, log[-6000:]
