"""Shared fixtures: the OpenCL queue tests run on (PoCL on the CPU in CI), shared data."""

import os
from pathlib import Path

import numpy as np
import pytest

from clnlos import runtime

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture(scope="session")
def queue():
    """One queue on the test device: $CLNLOS_DEVICE, else PoCL if present, else the default."""
    spec = os.environ.get(runtime.ENV_DEVICE) or None
    if spec is None and any("portable" in d.platform.lower() for d in runtime.list_devices()):
        spec = "pocl"
    return runtime.get_queue(spec)


@pytest.fixture(params=[np.float32, np.float64], ids=["f32", "f64"])
def dtype(request, queue):
    if request.param == np.float64 and not runtime.has_fp64(queue.device):
        pytest.skip("device has no fp64")
    return np.dtype(request.param)


@pytest.fixture(scope="session")
def shared_data():
    if not SHARED.is_dir():
        pytest.skip("../shared/data not present")
    return SHARED

