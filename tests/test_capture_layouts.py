"""Other groups' files as they come (issue 58, items 1, 2 and 7): the layout of an array that
records none is said in a note and settable (``--axes``, ``axes=``, ``[capture] axes``), with
it a capture stored in another order reconstructs upright; MATLAB v7.3 is recognised by its
header and read in MATLAB's order, one 3-D array under any name; HDF5 of another tool; what a
layout does not store is taken from its published code with a note."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
import scipy.io
from reference.scene_ref import points_transient

import clnlos
from clnlos.app.cli import main
from clnlos.errors import InputFileError, ParameterError
from clnlos.io.formats import sniff
from clnlos.io.formats.mat import FK_MAT_BIN_WIDTH_S, FK_SCAN_WIDTH_M
from clnlos.io.layout import assumed_layout, parse_axes

NT, N, DT, WIDTH = 96, 12, 32e-12, 0.4
GEOMETRY = ["--bin-width", f"{DT:g}", "--scan-width", f"{WIDTH:g}"]
MAT73_HEADER = (b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Jan  1 00:00:00 "
                b"2024 HDF5 schema 1.00 .")


def write_mat73(path, variables: dict) -> None:
    """A MATLAB v7.3 file as MATLAB writes it: HDF5 behind a 512-byte user block holding the
    header text, each array stored with its axes reversed (MATLAB's column-major order)."""
    with h5py.File(path, "w", userblock_size=512) as f:
        for name, a in variables.items():
            f.create_dataset(name, data=np.ascontiguousarray(np.transpose(np.asarray(a))))
    with open(path, "r+b") as fh:
        fh.write(MAT73_HEADER.ljust(116, b" ") + b"\x00" * 8 + b"\x00\x02IM")


def ncc(a, b) -> float:
    a, b = a - a.mean(), b - b.mean()
    return float((a * b).sum() / np.sqrt((a * a).sum() * (b * b).sum()))


@pytest.fixture(scope="module")
def target():
    """[t, y, x] of three points of unequal brightness: an L on its side, mirrored or
    turned, is another picture (no symmetry a wrong layout could keep)."""
    pts = [(-0.1, 0.1, 0.3), (-0.1, -0.08, 0.32), (0.09, -0.08, 0.34)]
    return points_transient(pts, [1.0, 0.6, 0.3], NT, N, WIDTH, DT).astype(np.float32)


def front(path, *flags) -> np.ndarray:
    """The front view of ``path`` reconstructed by the CLI with ``flags`` (LCT)."""
    out = path.with_name(f"{path.stem}_{len(flags)}_v.h5")
    assert main(["reconstruct", str(path), "-o", str(out), "--force", "--inversion-snr",
                 "1e3", *GEOMETRY, *flags]) == 0
    with h5py.File(out) as f:
        if "--axes" in flags:  # the layout used is recorded in the output
            assert f.attrs["capture_axes"] == flags[flags.index("--axes") + 1]
            assert f.attrs["capture_axes_source"] == "given"
        return f["volume"][()].max(axis=0)


def test_layout_text_round_trips_and_refuses_what_is_not_one():
    a = np.arange(5 * 3 * 4).reshape(5, 3, 4)
    for spec in ("t,y,x", "x,-y,t", "-y,x,t", "y,-t,-x"):
        lay = parse_axes(spec)
        assert str(lay) == spec and np.array_equal(lay.to_tyx(lay.from_tyx(a)), a)
    assert parse_axes(" X , -Y,T ").to_tyx(a.transpose(2, 1, 0)[:, ::-1]).tolist() == a.tolist()
    for bad in ("t,y", "t,t,x", "t,--y,x", "t,y,z", 3):
        with pytest.raises(ParameterError, match="t, y and x each once"):
            parse_axes(bad)
    # assumed: time on a longer axis than the first, else first
    assert [str(assumed_layout(s)) for s in ((64, 64, 512), (512, 64, 64), (16, 16, 16))] == \
        ["y,x,t", "t,y,x", "t,y,x"]


def test_npy_in_another_order_is_noted_and_reads_upright_with_axes(tmp_path, target, capsys):
    np.save(tmp_path / "ref.npy", target)
    ref = front(tmp_path / "ref.npy")
    np.save(tmp_path / "t_x_y.npy", target.transpose(0, 2, 1))  # y-tal's T_Sx_Sy
    capsys.readouterr()
    wrong = front(tmp_path / "t_x_y.npy")
    err = capsys.readouterr().err
    note = next(line for line in err.splitlines() if "read as axes t,y,x" in line)
    assert note.startswith("clnlos: note: ") and "t_x_y.npy: the array" in note
    assert "axis 1 (12) up the front view; axis 2 (12) to the right" in note
    assert "--axes" in note
    assert ncc(wrong, ref) < 0.5  # on its side
    assert ncc(front(tmp_path / "t_x_y.npy", "--axes", "t,x,y"), ref) > 0.999
    assert "read as axes" not in capsys.readouterr().err  # a layout given: nothing assumed
    # the time axis last, y stored top to bottom; the config's [capture] axes says the same
    np.save(tmp_path / "yx_t.npy", target[:, ::-1].transpose(1, 2, 0))
    (tmp_path / "p.toml").write_text('[capture]\naxes = "-y,x,t"\n')
    assert ncc(front(tmp_path / "yx_t.npy", "--config", str(tmp_path / "p.toml")), ref) > 0.999


def test_matlab_v73_is_recognised_by_its_header_one_array_of_any_name(tmp_path, target):
    """The f-k reductions' shape: one array ``tof_data`` of MATLAB size (N, N, T), rows
    running down; read in MATLAB's order (h5py's reversed), named in the note."""
    stored = parse_axes("-y,x,t").from_tyx(target)
    write_mat73(tmp_path / "statue.mat", {"tof_data": stored})
    assert sniff(tmp_path / "statue.mat") == "mat73"
    cap = clnlos.read_capture(tmp_path / "statue.mat")
    assert cap.attrs["axes"] == "y,x,t" and "'tof_data'" in cap.attrs["axes_array"]
    assert cap.bin_width_s is None and cap.scan_width_m is None
    rec = clnlos.reconstruct(tmp_path / "statue.mat", bin_width_s=DT, scan_width_m=WIDTH,
                             inversion_snr=1e3)
    assert any("variable 'tof_data' (MATLAB's order) read as axes y,x,t" in n
               for n in rec.notes)
    given = clnlos.reconstruct(tmp_path / "statue.mat", axes="-y,x,t", bin_width_s=DT,
                               scan_width_m=WIDTH, inversion_snr=1e3)
    ref = clnlos.reconstruct(target, bin_width_s=DT, scan_width_m=WIDTH, inversion_snr=1e3)
    assert ncc(given.volume.max(0), ref.volume.max(0)) > 0.999
    assert given.params["axes_used"] == "-y,x,t" and given.params["axes_source"] == "given"
    # v5 with any name; several arrays: the error names them
    scipy.io.savemat(tmp_path / "v5.mat", {"histograms": stored})
    assert clnlos.read_capture(tmp_path / "v5.mat", axes="-y,x,t").transient.tolist() == \
        target.tolist()
    write_mat73(tmp_path / "two.mat", {"a": stored, "b": stored})
    with pytest.raises(InputFileError, match=r"2 3-D variables \(a .*, b .*\)"):
        clnlos.read_capture(tmp_path / "two.mat")


def test_hdf5_of_another_tool_and_formats_that_record_their_layout(tmp_path, target):
    with h5py.File(tmp_path / "other.h5", "w") as f:
        f["scan/counts"] = target.transpose(2, 1, 0)  # x, y, t
    cap = clnlos.read_capture(tmp_path / "other.h5", axes="x,y,t")
    assert np.array_equal(cap.transient, target) and "'scan/counts'" in cap.attrs["axes_array"]
    clnlos.io.files.write_capture(tmp_path / "own.h5", target, bin_width_s=DT, start_s=0.0,
                                  scan_width_m=WIDTH)
    with pytest.raises(InputFileError, match=r"records its layout .*axes x,y,t"):
        clnlos.read_capture(tmp_path / "own.h5", axes="x,y,t")
    assert main(["reconstruct", str(tmp_path / "own.h5"), "-o", str(tmp_path / "v.h5"),
                 "--axes", "x,y,t"]) == 2
    assert not (tmp_path / "v.h5").exists()
    assert main(["reconstruct", str(tmp_path / "own.h5"), "-o", str(tmp_path / "v.h5"),
                 "--axes", "t,y"]) == 2
    # a capture read from a file is read again with the layout asked for
    np.save(tmp_path / "c.npy", target.transpose(0, 2, 1))
    turned = clnlos.reconstruct(clnlos.read_capture(tmp_path / "c.npy"), axes="t,x,y",
                                bin_width_s=DT, scan_width_m=WIDTH, inversion_snr=1e3)
    assert turned.params["axes_used"] == "t,x,y"


def test_parameters_a_layout_does_not_store_are_noted(tmp_path, target):
    """f-k: 32 ps and the release's 2 m scan (its demo.m), noted; CDT: 16 ps, noted, and
    the scan width it sets per scene asked for."""
    scipy.io.savemat(tmp_path / "fk.mat", {"meas": parse_axes("-y,x,t").from_tyx(target),
                                            "tofgrid": np.zeros((N, N))})
    cap = clnlos.read_capture(tmp_path / "fk.mat")
    assert (cap.bin_width_s, cap.scan_width_m) == (FK_MAT_BIN_WIDTH_S, FK_SCAN_WIDTH_M)
    rec = clnlos.reconstruct(cap, inversion_snr=1e3)
    said = next(n for n in rec.notes if "bin width 32 ps" in n)
    assert "scan width 2 m: the published demo.m's wall_size" in said
    assert "start 0 ps: each scan point's 'tofgrid' removed" in said
    assert said.endswith("override with bin_width_s=, scan_width_m=, start_s=)")  # Python
    rec = clnlos.reconstruct(cap, inversion_snr=1e3, bin_width_s=DT)
    assert not any("bin width 32 ps" in n for n in rec.notes)
    assert any(n.count(": ") and "scan width 2 m" in n for n in rec.notes)
    scipy.io.savemat(tmp_path / "cdt.mat", {"meas": parse_axes("t,-y,x").from_tyx(target)})
    with pytest.raises(clnlos.errors.MissingParameterError, match="per scene, 0.6-0.7 m"):
        clnlos.reconstruct(tmp_path / "cdt.mat")
    rec = clnlos.reconstruct(tmp_path / "cdt.mat", scan_width_m=WIDTH, inversion_snr=1e3)
    assert any("bin width 16 ps: the published code's 16 ps (cdt_reconstruction.py)" in n
               for n in rec.notes)


def test_read_capture_of_an_array_and_of_what_is_neither(target):
    cap = clnlos.read_capture(target.transpose(2, 1, 0), axes="x,y,t")
    assert np.array_equal(cap.transient, target) and cap.attrs["axes_source"] == "given"
    assert clnlos.read_capture(target).attrs["axes"] == "t,y,x"
    for bad in (None, 3, [1, 2]):
        with pytest.raises(TypeError, match=r"^path: expected a capture file path"):
            clnlos.read_capture(bad)
