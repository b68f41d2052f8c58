"""Shared fixtures: the OpenCL queue tests run on (PoCL on the CPU in CI), shared data."""

import os
from pathlib import Path

import numpy as np
import pytest

from clnlos import settings
from clnlos.runtime import device as runtime

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def device_queue():
    """The queue tests run on: $CLNLOS_DEVICE, else PoCL if present, else the default (one
    per process: clnlos.runtime.caches keeps it)."""
    spec = os.environ.get(settings.ENV_DEVICE) or None
    if spec is None and any("portable" in d.platform.lower() for d in runtime.list_devices()):
        spec = "pocl"
    return runtime.get_queue(spec)


@pytest.fixture(scope="session")
def queue():
    """One queue on the test device (:func:`device_queue`)."""
    return device_queue()


@pytest.fixture(params=[np.float32, np.float64], ids=["f32", "f64"])
def dtype(request, queue):
    if request.param == np.float64 and not runtime.has_fp64(queue.device):
        pytest.skip("device has no fp64")
    return np.dtype(request.param)


def pytest_runtest_setup(item):
    """A test marked ``fp64`` runs float64 on the device: skipped, with that reason, on a
    device without cl_khr_fp64 (rusticl/llvmpipe, many GPUs), before its fixtures are set
    up; its float32 path is covered against host float64 references by the other tests. Any
    other test that meets a "float64 requested" refusal fails."""
    if item.get_closest_marker("fp64") is not None \
            and not runtime.has_fp64(device_queue().device):
        pytest.skip("the device has no fp64, this test needs a float64 device run")


@pytest.fixture(scope="session")
def shared_data():
    if not SHARED.is_dir():
        pytest.skip("../shared/data not present")
    return SHARED

