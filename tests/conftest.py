"""Shared fixtures: the OpenCL queue tests run on (PoCL on the CPU in CI), shared data."""

import os
from pathlib import Path

import numpy as np
import pytest

from clnlos import settings
from clnlos.runtime import device as runtime

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture(scope="session")
def queue():
    """One queue on the test device: $CLNLOS_DEVICE, else PoCL if present, else the default."""
    spec = os.environ.get(settings.ENV_DEVICE) or None
    if spec is None and any("portable" in d.platform.lower() for d in runtime.list_devices()):
        spec = "pocl"
    return runtime.get_queue(spec)


@pytest.fixture(params=[np.float32, np.float64], ids=["f32", "f64"])
def dtype(request, queue):
    if request.param == np.float64 and not runtime.has_fp64(queue.device):
        pytest.skip("device has no fp64")
    return np.dtype(request.param)


def _fp64_missing(excinfo) -> bool:
    """A float64 request refused by a device without cl_khr_fp64 (or a float64 kernel build
    that failed for that reason)."""
    from clnlos.errors import DeviceCapabilityError, KernelBuildError

    msg = str(excinfo.value)
    return ((excinfo.errisinstance(DeviceCapabilityError) and "float64 requested" in msg)
            or (excinfo.errisinstance(KernelBuildError) and "REAL_T=double" in msg
                and "fp64" in msg))


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    """On a device without fp64 (rusticl/llvmpipe, many GPUs), a test whose float64 device
    reference is refused is reported as skipped with that reason, not failed: the float32
    path it checks is covered against host float64 references by the other tests."""
    outcome = yield
    rep = outcome.get_result()
    if call.when in ("setup", "call") and call.excinfo is not None \
            and _fp64_missing(call.excinfo):
        rep.outcome = "skipped"
        rep.longrepr = (str(item.path), item.location[1] or 0,
                        "Skipped: the device has no fp64, this test needs a float64 device run")


@pytest.fixture(scope="session")
def shared_data():
    if not SHARED.is_dir():
        pytest.skip("../shared/data not present")
    return SHARED

