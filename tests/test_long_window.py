"""Long time windows: the iterative method sums a capture's bins only where the band the sum
removes holds nothing but photon noise (:func:`clnlos.inverse.preprocessing.bandwidth_bins`),
with a note; a capture that is not counts, or whose band holds signal, keeps every bin."""

import numpy as np
import pytest

from clnlos.config import ReconstructionConfig
from clnlos.inverse.methods import ITERATIVE_SUM_BINS_ABOVE
from clnlos.inverse.pipeline import reconstruct
from clnlos.inverse.preprocessing import band_excess, bandwidth_bins
from clnlos.io.capture import Capture

DT = 4e-12


def _counts(width_s: float, *, nt: int = 2048, n: int = 4, peak: float = 200.0, seed=0):
    """Poisson counts [t, y, x] of a background of 0.5 per bin and Gaussian arrivals of rms
    duration ``width_s`` (a different delay per scan point)."""
    t = (np.arange(nt) + 0.5) * DT
    rng = np.random.default_rng(seed)
    delays = rng.uniform(0.7, 0.9, (n, n)) * nt * DT
    lam = 0.5 + peak * np.exp(-0.5 * ((t[:, None, None] - delays) / width_s) ** 2)
    return rng.poisson(lam).astype(np.float32)


def test_a_band_of_noise_alone_is_summed_away_and_signal_is_kept():
    """60 ps arrivals hold nothing above a few GHz: the 2048 bins of 4 ps are summed to
    ITERATIVE_SUM_BINS_ABOVE, with the band's excess in the note; 3 ps arrivals hold signal up
    to the 4 ps grid's Nyquist: every bin kept; floats that are not counts (a noise-free
    render) and windows within the threshold are never summed."""
    smooth = _counts(60e-12)
    bins, note = bandwidth_bins(smooth, bins_kept=2048, bin_width_s=DT, start_s=0.0,
                                above=ITERATIVE_SUM_BINS_ABOVE)
    assert bins == ITERATIVE_SUM_BINS_ABOVE and "16 ps" in note and "Poisson noise" in note
    sharp = _counts(3e-12, peak=2000.0)
    assert band_excess(sharp, (0, 2048), DT, (1 / (4 * DT), 1 / (2 * DT))) > 6
    assert bandwidth_bins(sharp, bins_kept=2048, bin_width_s=DT, start_s=0.0,
                          above=ITERATIVE_SUM_BINS_ABOVE) == (None, None)
    noise_free = smooth + np.float32(0.25)  # not counts: no noise to tell signal from
    assert bandwidth_bins(noise_free, bins_kept=2048, bin_width_s=DT, start_s=0.0,
                          above=ITERATIVE_SUM_BINS_ABOVE) == (None, None)
    assert bandwidth_bins(smooth[:500], bins_kept=500, bin_width_s=DT, start_s=0.0,
                          above=ITERATIVE_SUM_BINS_ABOVE) == (None, None)


def test_white_noise_is_within_its_bounds():
    """Poisson noise alone: the band excess is a standard normal variable (|z| < 4 here for
    every band tried: the rule's 6 sd is not reached by chance)."""
    y = np.random.default_rng(5).poisson(3.0, (1024, 8, 8)).astype(np.float32)
    for lo, hi in ((1e9, 3e9), (3e9, 6e9), (31e9, 62e9), (62e9, 125e9)):
        assert abs(band_excess(y, (0, 1024), DT, (lo, hi))) < 4


@pytest.mark.parametrize("method", ["iterative", "lct"])
def test_reconstruct_says_when_it_sums_and_the_user_keeps_the_bins(queue, method):
    """Through reconstruct: the iterative method sums the noise-only band of a long capture
    and says so in a note; LCT (cost not per iteration) and a user's bins keep theirs."""
    cap = Capture(_counts(60e-12, nt=1024, n=4), DT, 0.0, 0.4)
    cfg = ReconstructionConfig(method=method, iterations=3).validate()
    rec = reconstruct(cap, cfg, device=queue)
    summed = [n for n in rec.notes if "Poisson noise" in n]
    if method == "iterative":
        assert rec.volume.shape[0] == ITERATIVE_SUM_BINS_ABOVE and len(summed) == 1
    else:
        assert rec.volume.shape[0] == 1024 and not summed
    kept = reconstruct(cap, cfg.replace(bins=1024).validate({"bins": "--bins"}), device=queue)
    assert kept.volume.shape[0] == 1024 and not [n for n in kept.notes if "Poisson" in n]
