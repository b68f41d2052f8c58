"""OpenCL runtime: device selection, program cache, build errors, capability checks."""

import json
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from clnlos import settings
from clnlos.app.cli import main
from clnlos.errors import DeviceCapabilityError, DeviceError, KernelBuildError
from clnlos.runtime import device as runtime
from clnlos.runtime import caches, fft, programs

ROOT = Path(__file__).resolve().parents[1]


def test_list_devices_has_pocl():
    devs = runtime.list_devices()
    assert devs and all(d.compute_units >= 1 and d.global_mem_bytes > 0 for d in devs)
    assert any("portable" in d.platform.lower() for d in devs) or os.environ.get("CLNLOS_DEVICE")


@pytest.mark.parametrize("spec", ["0:0", "pocl", "portable", "cpu", "portable:0"])
def test_select_device_specs(spec):
    if spec in ("pocl", "portable", "portable:0") and not any(
            "portable" in d.platform.lower() for d in runtime.list_devices()):
        pytest.skip("no PoCL")
    dev = runtime.select_device(spec)
    assert dev.name


def test_env_selects_device(monkeypatch):
    monkeypatch.setenv(settings.ENV_DEVICE, "0:0")
    assert runtime.select_device(None) == runtime.select_device("0:0")
    monkeypatch.setenv(settings.ENV_DEVICE, "no-such-device")
    with pytest.raises(DeviceError, match="no-such-device"):
        runtime.select_device(None)


@pytest.mark.parametrize("spec", ["9:9", "nvidia-nonexistent", "pocl:7", ":"])
def test_bad_device_spec_is_clear(spec):
    with pytest.raises(DeviceError):
        runtime.select_device(spec)


def test_program_cache_and_kernels_fetched_once(queue):
    a = programs.get_kernels(queue, "diffusion", programs.real_defines(np.float32))
    b = programs.get_kernels(queue.context, "diffusion", programs.real_defines(np.float32))
    assert a is b
    assert a.transmittance_pairs is b.transmittance_pairs  # same cl.Kernel object
    c = programs.get_kernels(queue, "diffusion", {"REAL_T": "float", "X_EXTRA": 3})
    assert c is not a and "-DX_EXTRA=3" in c.options


def test_build_failure_names_file_options_device(queue):
    with pytest.raises(KernelBuildError) as ei:
        programs.get_kernels(queue, "diffusion", {"REAL_T": "no_such_type"})
    msg = str(ei.value)
    assert "diffusion.cl" in msg and "-DREAL_T=no_such_type" in msg
    assert queue.device.name.strip() in msg


def test_missing_kernel_family(queue):
    with pytest.raises(KernelBuildError, match="not found"):
        programs.get_kernels(queue, "no_such_family")


class _NoFp64Device:
    name = "fake device without fp64"
    extensions = "cl_khr_byte_addressable_store"
    double_fp_config = 0


def test_fp64_capability_error():
    with pytest.raises(DeviceCapabilityError, match="cl_khr_fp64"):
        runtime.require_dtype(_NoFp64Device(), np.float64)
    assert runtime.require_dtype(_NoFp64Device(), np.float32) == np.float32
    with pytest.raises(DeviceCapabilityError):
        runtime.require_dtype(_NoFp64Device(), np.int32)


def test_memory_check_before_allocation(queue):
    with pytest.raises(DeviceCapabilityError, match="MiB"):
        runtime.require_memory(queue.device, queue.device.global_mem_size * 4, "test volume")


def test_fft_backend_choice(queue, monkeypatch):
    monkeypatch.delenv(settings.ENV_FFT, raising=False)
    monkeypatch.setattr(fft, "pocl_version", lambda dev: (7, 0))
    c = fft.fft_backend(queue)
    assert c.backend == "host" and "2069" in c.reason and c.warn
    monkeypatch.setattr(fft, "pocl_version", lambda dev: (3, 1))
    c = fft.fft_backend(queue)
    if queue.device.type & runtime.cl.device_type.CPU:
        assert c.backend == "host" and "CPU" in c.reason and not c.warn
    monkeypatch.setenv(settings.ENV_FFT, "host")
    assert fft.fft_backend(queue) == fft.FFTChoice("host", "CLNLOS_FFT=host")
    monkeypatch.setenv(settings.ENV_FFT, "bogus")
    with pytest.raises(DeviceError, match="CLNLOS_FFT"):
        fft.fft_backend(queue)


def test_forced_vkfft_without_pyvkfft_is_an_error(queue, monkeypatch):
    import builtins

    real_import = builtins.__import__

    def no_vkfft(name, *a, **kw):
        if name.startswith("pyvkfft"):
            raise ImportError("no pyvkfft here")
        return real_import(name, *a, **kw)

    monkeypatch.setattr(builtins, "__import__", no_vkfft)
    monkeypatch.setenv(settings.ENV_FFT, "vkfft")
    with pytest.raises(DeviceError, match="pyvkfft"):
        fft.fft_backend(queue)
    monkeypatch.setenv(settings.ENV_FFT, "auto")
    assert fft.fft_backend(queue).backend == "host"


def test_cli_devices_lists_and_marks_default(capsys):
    assert main(["devices"]) == 0
    out = capsys.readouterr().out
    assert "fp64" in out and "*" in out and "0:0" in out


@pytest.mark.parametrize("spec,env", [("9:9", None), ("nosuch:9", None), ("nosuch", None),
                                      ("gpu:7", None), (None, "9:9"), (None, "nosuch")])
def test_cli_devices_spec_matching_nothing_is_an_error(capsys, monkeypatch, spec, env):
    if env is None:
        monkeypatch.delenv(settings.ENV_DEVICE, raising=False)
    else:
        monkeypatch.setenv(settings.ENV_DEVICE, env)
    assert main(["devices"] + (["--device", spec] if spec else [])) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("clnlos: error: no OpenCL device")


def test_cli_bad_device_one_line_exit_2(capsys):
    rc = subprocess.run([sys.executable, "-m", "clnlos", "devices", "--bogus-flag"],
                        capture_output=True, text=True)
    assert rc.returncode == 2 and "Traceback" not in rc.stderr
    assert len(rc.stderr.strip().splitlines()) == 1


@pytest.mark.slow
def test_wheel_ships_kernels_and_runs_them(tmp_path):
    """Build a wheel, install it into an empty target dir and run a kernel from there only."""
    import shutil

    wheel_dir = tmp_path / "wheel"
    src = tmp_path / "src"  # a clean copy: a build/ left in the checkout could add old modules
    shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns(
        ".git", ".venv", "build", "out", "*.egg-info", "__pycache__", "tests", "tools", "docs"))
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation",
                        "-q", "-w", str(wheel_dir), str(src)], capture_output=True, text=True)
    if r.returncode != 0 and "No module named" in r.stderr:
        pytest.skip(f"cannot build a wheel here: {r.stderr.strip()[-200:]}")
    assert r.returncode == 0, r.stderr
    whl = next(wheel_dir.glob("clnlos-*.whl"))
    names = zipfile.ZipFile(whl).namelist()
    shipped = {n for n in names if n.startswith("clnlos/") and n.endswith(".py")}
    source = {f"clnlos/{p.relative_to(ROOT / 'clnlos').as_posix()}"
              for p in (ROOT / "clnlos").rglob("*.py") if "__pycache__" not in p.parts}
    source |= {f"clnlos/kernels/{p.name}" for p in (ROOT / "kernels").glob("*.py")}
    assert shipped == source, (sorted(shipped - source), sorted(source - shipped))
    assert "clnlos/py.typed" in names  # PEP 561: the API's annotations reach type checkers
    import clnlos

    assert whl.name.startswith(f"clnlos-{clnlos.__version__}-")  # the one stated version
    for k in (ROOT / "kernels").glob("*.[ch]*"):
        if k.suffix in (".cl", ".h"):
            assert f"clnlos/kernels/{k.name}" in names, k.name
    target = tmp_path / "site"
    r = subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "--no-index", "-q",
                        "--target", str(target), str(whl)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    code = (
        "import clnlos, clnlos.runtime.programs as rt, clnlos.runtime.device as dev\n"
        "import clnlos.diffusion as d, pathlib, sys\n"
        f"assert pathlib.Path(clnlos.__file__).is_relative_to({str(target)!r}), clnlos.__file__\n"
        "names = sorted(p.name for p in rt.kernel_dir().iterdir() if p.name.endswith('.cl'))\n"
        "q = dev.get_queue()\n"
        "import clnlos.forward.scene as b\n"
        "extra = {'bistatic': {'N_PHI': b.FACE_ANGLES}}  # the defines a family needs\n"
        "for fam in names:\n"
        "    rt.get_kernels(q, fam[:-3], {**rt.real_defines('float32'),\n"
        "                                 **extra.get(fam[:-3], {})})\n"
        "v = d.slab_transmittance(0.0, 1e-9, thickness_m=0.0254, mu_a=0.53,\n"
        "                         mu_s_prime=262.0, n=1.12)\n"
        "assert v > 0\n"
        "print(len(names))\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["PYTHONPATH"] = str(target)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       cwd=tmp_path, env=env)
    assert r.returncode == 0, r.stderr
    assert int(r.stdout.strip()) == len(list((ROOT / "kernels").glob("*.cl")))
    # the installed package runs its benchmark harness and reports its version (no
    # source checkout: the folder holds only the wheel's files)
    r = subprocess.run([sys.executable, "-m", "clnlos", "bench", "--tiny", "--only",
                        "diffusion,iterative", "-o", str(tmp_path / "bench")],
                       capture_output=True, text=True, cwd=tmp_path, env=env, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    doc = json.loads((tmp_path / "bench" / "bench.json").read_text())
    assert {row["kernel"] for row in doc["rows"]} >= {"diffusion", "inversion_quality"}
    r = subprocess.run([sys.executable, "-m", "clnlos", "--version"], capture_output=True,
                       text=True, cwd=tmp_path, env=env)
    assert r.returncode == 0 and r.stdout.startswith("clnlos ")


def test_host_copies_respect_offsets_and_keep_no_events(queue):
    """buffers.download / upload_into: a slice with an offset round-trips, and no event (each
    of which would hold a host buffer) is left on the array -- Array.get()/set() keep up to
    12 per array, which made the host-FFT path hold 12 copies of its plan buffers."""
    import pyopencl.array as cla

    from clnlos.errors import ShapeError
    from clnlos.runtime.buffers import download, upload_into

    a = cla.to_device(queue, np.arange(24, dtype=np.float32).reshape(4, 6))
    a.finish()
    tail = a[2:]
    np.testing.assert_array_equal(download(tail), np.arange(12, 24).reshape(2, 6))
    upload_into(tail, -np.ones((2, 6)))
    np.testing.assert_array_equal(download(a)[2:], -1)
    np.testing.assert_array_equal(download(a)[:2], np.arange(12).reshape(2, 6))
    for _ in range(20):
        upload_into(a, download(a))
    assert not a.events and not tail.events
    with pytest.raises(ShapeError):
        upload_into(a, np.zeros((3, 6)))


@pytest.mark.parametrize("shape", [(16, 6, 8), (12, 5, 7)])
def test_inverse_of_low_rows_pads_them_itself(queue, monkeypatch, shape):
    """ComplexFFT3.inverse_low_rows (the f-k Stolt spectrum, zero past its low rows, never
    stored whole): the low-corner block of numpy's ifftn of the zero-padded grid, also
    where the pass along t takes several blocks of columns."""
    import pyopencl.array as cla

    from clnlos.runtime.buffers import download

    monkeypatch.setattr(fft, "LOW_ROWS_BLOCK", 40)  # several column blocks along t
    rng = np.random.default_rng(2)
    m, needed = shape[0] // 2, (shape[0] // 2, 3, 4)
    low = (rng.standard_normal((m,) + shape[1:])
           + 1j * rng.standard_normal((m,) + shape[1:])).astype(np.complex64)
    whole = np.zeros(shape, np.complex64)
    whole[:m] = low
    want = np.fft.ifftn(whole)[:needed[0], :needed[1], :needed[2]]
    plan = fft.ComplexFFT3(shape, np.float32, queue)
    if not plan.low_rows:
        pytest.skip("VkFFT plan: the whole grid is stored")
    got = download(plan.inverse_low_rows(cla.to_device(queue, low), needed=needed))
    np.testing.assert_allclose(got[:needed[0], :needed[1], :needed[2]], want,
                               atol=1e-5 * np.abs(want).max())


def test_plan_cache_budget_clear_and_threads(queue, monkeypatch):
    """Plans are reused per key and thread, evicted least-recently-used past the byte budget,
    and freed by clear()."""
    import threading

    import pyopencl.array as cla

    from clnlos.errors import ParameterError
    from clnlos.runtime.caches import PlanCache, device_bytes
    from clnlos.settings import ENV_PLAN_CACHE_MB as ENV_BUDGET

    class Plan:
        def __init__(self, n):
            self.buf = cla.zeros(queue, n, np.float32)
            self.inner = {"spec": cla.zeros(queue, n, np.complex64)}

    assert device_bytes(Plan(100)) == 100 * 4 + 100 * 8
    # shared work buffers count with their reserved size, before and after allocation
    from clnlos.runtime.buffers import Scratch

    plan = Plan(100)
    plan.scratch = Scratch(queue)
    plan.scratch.reserve("a", (10, 10), np.float32)
    plan.scratch.reserve("a", (50,), np.complex64)  # the slot takes the larger need
    assert device_bytes(plan) == 1200 + 400
    plan.scratch.array("b", (25,), np.float32)
    assert device_bytes(plan) == 1200 + 400 + 100 == 1200 + plan.scratch.nbytes
    built = []

    def build(n):
        built.append(n)
        return Plan(n)

    cache = PlanCache("test", budget_bytes=3 * 1200 * 10)
    a = cache.get("a", lambda: build(1000))
    assert cache.get("a", lambda: build(1000)) is a and built == [1000]
    cache.get("b", lambda: build(1000))
    cache.get("a", lambda: build(1000))  # a becomes the most recently used
    cache.get("c", lambda: build(1000))  # 3 x 12000 B: exactly the budget
    assert len(cache) == 3 and cache.nbytes == 36000
    cache.get("d", lambda: build(1000))  # evicts b, the least recently used
    assert len(cache) == 3 and cache.get("a", lambda: build(1)) is a
    cache.get("b", lambda: build(1000))
    assert built == [1000] * 5
    other = []
    t = threading.Thread(target=lambda: other.append(cache.get("a", lambda: build(1000))))
    t.start()
    t.join()
    assert other[0] is not a  # plans own scratch buffers: one per thread
    cache.clear()
    assert len(cache) == 0 and cache.nbytes == 0
    monkeypatch.setenv(ENV_BUDGET, "0.5")
    assert PlanCache("env").budget() == 2**19
    monkeypatch.setenv(ENV_BUDGET, "lots")
    with pytest.raises(ParameterError, match=ENV_BUDGET):
        PlanCache("env").budget()


def test_scratch_slots_are_shared_views_that_grow_to_the_largest_need(queue):
    """Stages that reserve the same slot get views of one buffer (a write through one view
    is seen through another of another dtype); a need larger than the buffer gives a new,
    larger buffer."""
    from clnlos.runtime.buffers import Scratch

    s = Scratch(queue)
    s.reserve("a", (4, 8), np.float32)
    s.reserve("a", (16,), np.complex64)
    r = s.array("a", (4, 8), np.float32)
    c = s.array("a", (16,), np.complex64)
    assert r.data.int_ptr == c.data.int_ptr and r.data.size == 128
    r.set(np.arange(32, dtype=np.float32).reshape(4, 8))
    np.testing.assert_array_equal(c.get().view(np.float32), np.arange(32))
    big = s.array("a", (64,), np.float32)
    assert big.data.size == 256 and s.nbytes == 256
    assert s.array("b", (3,), np.float64).shape == (3,)


CLEAR_ALL = """
import clnlos.forward.blur as blur
from clnlos.physics.slab import CDT_SLAB
from clnlos.runtime import caches, device, programs
from clnlos.runtime import fft as fft_mod

expected = {"OpenCL contexts", "OpenCL queues", "built programs", "VkFFT apps",
            "reconstruction pipelines", "forward-model slab blurs", "blur margins"}
assert expected <= set(caches.CACHES.names), caches.CACHES.names
queue = device.get_queue()
programs.get_kernels(queue, "fill")
blur.blur_margin(CDT_SLAB, 1e-9, 0.01, 8, 1e-3, None, queue)
caches.PIPELINES.get("k", lambda: object())
caches.FORWARD_BLURS.get("k", lambda: object())

def held():
    return (blur.blur_margin.cache_info().currsize, len(caches.PIPELINES),
            len(caches.FORWARD_BLURS), len(programs._program_cache),
            device._queue_for.cache_info().currsize, device._context_for.cache_info().currsize)

assert all(held()), held()
caches.CACHES.clear()
assert held() == (0,) * 6 and fft_mod._vkfft_app.cache_info().currsize == 0, held()
k = programs.get_kernels(device.get_queue(), "fill")  # rebuilt on demand
print("ok")
"""


def test_one_registry_clears_every_cache():
    """CACHES.clear() empties the contexts, queues, programs, VkFFT apps (filled on GPUs
    only), both plan caches and the blur margins (each module registers its cache when
    imported); in a child process, so the session's queue stays valid."""
    r = subprocess.run([sys.executable, "-c", CLEAR_ALL], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr


def test_kernel_binaries_cached_on_disk_keyed_by_the_headers(queue, tmp_path, monkeypatch):
    """Built programs go to pyopencl's on-disk binary cache (also on PoCL, where pyopencl
    itself would skip it): a second build of the same family adds nothing there, a family
    whose sources hash differently (an edited header) is a new entry, and both build."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))  # pyopencl's cache folder under it

    def entries() -> int:
        return sum(1 for p in (tmp_path / "pyopencl").rglob("*") if p.is_file())

    def build():
        caches.CACHES.clear()  # the in-memory program cache: the disk is asked again
        return programs.get_kernels(queue, "resample", programs.real_defines(np.float32))

    assert build().scale_inplace is not None
    first = entries()
    assert first > 0
    build()
    assert entries() == first
    src, digest = programs.source_with_headers("resample")
    monkeypatch.setattr(programs, "source_with_headers",
                        lambda family: (src, digest[::-1]))  # the same text, other headers
    assert build().scale_inplace is not None
    assert entries() > first


def test_single_threaded_blas_sets_and_restores_openblas_threads():
    """Inside the block OpenBLAS's thread-local count is one, on leaving the caller's again
    (the lobe's SVDs: 43.8 s with OpenBLAS's threads under load, 4.1 s with one)."""
    from clnlos.runtime.blas import _local_setter, single_threaded_blas

    fn = _local_setter()
    if fn is None:
        pytest.skip("no OpenBLAS with openblas_set_num_threads_local loaded (no-op there)")
    before = fn(2)
    with single_threaded_blas():
        assert fn(1) == 1
    assert fn(before) == 2
