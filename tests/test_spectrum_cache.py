"""The optional on-disk cache of PSF spectra (CLNLOS_SPECTRUM_CACHE)."""

import numpy as np
import pytest
from reference.scene_ref import points_transient

from clnlos.app.cli import main
from clnlos.config import ReconstructionConfig
from clnlos.inverse.pipeline import reconstruct
from clnlos.io.capture import Capture
from clnlos.io.files import write_capture
from clnlos.physics.slab import CDT_SLAB, Slab
from clnlos.runtime.caches import PIPELINES
from clnlos.runtime.spectrum_cache import SUFFIX

SHAPE_T, WIDTH, DT = 96, 0.5, 48e-12  # 4.6 ns: every arrival inside (no tail fill)


def _capture():
    tau = points_transient([(0.05, -0.03, 0.2), (-0.1, 0.08, 0.3)], [1, 1], SHAPE_T, 10,
                           WIDTH, DT)
    return Capture(tau.astype(np.float32), DT, 0.0, WIDTH)


def _run(queue, slab=CDT_SLAB, method="lct"):
    PIPELINES.clear()
    cfg = ReconstructionConfig(method=method, slab=slab, snr=1e4, inversion_snr=1e3).validate()
    return reconstruct(_capture(), cfg, device=queue).volume


def test_spectra_are_stored_then_read_back_instead_of_recomputed(queue, tmp_path,
                                                                 monkeypatch):
    monkeypatch.setenv("CLNLOS_SPECTRUM_CACHE", str(tmp_path / "spectra"))
    first = _run(queue)
    files = sorted((tmp_path / "spectra").glob(f"*{SUFFIX}"))
    assert len(files) == 2  # the slab's and the light cone's
    # a hit computes neither spectrum: make both builders fail
    import clnlos.forward.blur
    import clnlos.inverse.lct

    def boom(*a, **k):
        raise AssertionError("recomputed a cached spectrum")

    monkeypatch.setattr(clnlos.forward.blur, "phi_spectrum", boom)
    monkeypatch.setattr(clnlos.inverse.lct, "lightcone_psf_device", boom)
    np.testing.assert_array_equal(_run(queue), first)
    monkeypatch.undo()
    # another slab is another entry; a truncated entry is recomputed and replaced
    monkeypatch.setenv("CLNLOS_SPECTRUM_CACHE", str(tmp_path / "spectra"))
    _run(queue, Slab(thickness_m=0.0254, mu_a=1.0, mu_s_prime=262.0, n=1.12))
    assert len(list((tmp_path / "spectra").glob(f"*{SUFFIX}"))) == 3
    size = files[0].stat().st_size
    files[0].write_bytes(files[0].read_bytes()[: size // 2])
    with pytest.warns(UserWarning, match="truncated"):  # named in one warning
        np.testing.assert_array_equal(_run(queue), first)
    assert files[0].stat().st_size == size


def test_cache_folder_is_kept_under_its_budget(queue, tmp_path, monkeypatch):
    monkeypatch.setenv("CLNLOS_SPECTRUM_CACHE", str(tmp_path))
    _run(queue)
    one = max(p.stat().st_size for p in tmp_path.glob(f"*{SUFFIX}"))
    monkeypatch.setenv("CLNLOS_SPECTRUM_CACHE_MB", str(1.5 * one / 2**20))
    _run(queue, Slab(thickness_m=0.02, mu_a=0.53, mu_s_prime=262.0, n=1.12))
    total = sum(p.stat().st_size for p in tmp_path.glob(f"*{SUFFIX}"))
    assert 0 < total <= 1.5 * one


@pytest.mark.parametrize("env,value,needle", [
    ("CLNLOS_SPECTRUM_CACHE_MB", "lots", "CLNLOS_SPECTRUM_CACHE_MB"),
    ("CLNLOS_SPECTRUM_CACHE_MB", "-1", "CLNLOS_SPECTRUM_CACHE_MB"),
    ("CLNLOS_SPECTRUM_CACHE", "FILE", "CLNLOS_SPECTRUM_CACHE")])
def test_bad_cache_settings_are_one_line_errors_before_work(tmp_path, monkeypatch, capsys,
                                                            env, value, needle):
    cap = tmp_path / "c.h5"
    write_capture(cap, _capture().transient, bin_width_s=DT, start_s=0.0, scan_width_m=WIDTH)
    if value == "FILE":
        value = str(cap)  # a file, not a folder
    monkeypatch.setenv(env, value)
    assert main(["reconstruct", str(cap), "-o", str(tmp_path / "o.h5")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("clnlos: error:") and needle in err[0]
    assert not (tmp_path / "o.h5").exists()
