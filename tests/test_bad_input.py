"""Bad input from users (property-based): every case ends in one line naming the problem,
exit status 2, no traceback and no output file left behind."""

import contextlib
import io
import math

import h5py
import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from clnlos.cli import main

SETTINGS = settings(max_examples=25, deadline=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture])

GOOD_SCENE = {
    ("scan", "width_m"): 0.3, ("scan", "points"): 4,
    ("time", "bin_width_s"): 2e-11, ("time", "bins"): 64, ("time", "start_s"): 2e-9,
    ("slab", "thickness_m"): 0.0254, ("slab", "mu_a"): 0.53, ("slab", "mu_s_prime"): 262.0,
    ("slab", "n"): 1.12,
}
BAD_VALUES = st.one_of(st.just(-1.0), st.just(0), st.just(float("nan")), st.just(float("inf")),
                       st.just(1e300), st.just("text"), st.just([1, 2]), st.just(True),
                       st.integers(max_value=-1))


def _run(args):
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        rc = main(args)
    return rc, err.getvalue()


def _assert_clean_failure(rc, err, out_path):
    assert rc == 2, err
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert lines and lines[0].startswith("clnlos: error:"), err
    assert "Traceback" not in err
    assert not out_path.exists()
    assert not list(out_path.parent.glob(f".{out_path.name}.*"))


def _toml_value(v):
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float) and math.isnan(v):
        return "nan"
    if isinstance(v, float) and math.isinf(v):
        return "inf" if v > 0 else "-inf"
    if isinstance(v, str):
        return f'"{v}"'
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return repr(v)


def _scene_text(bad_key, bad_value):
    vals = dict(GOOD_SCENE)
    vals[bad_key] = bad_value
    out = []
    if bad_key[0] == "slab":
        vals[("time", "start_s")] = 0.0  # a slab needs t = 0 at bin 0
    else:
        vals = {k: v for k, v in vals.items() if k[0] != "slab"}
    for sec in ("scan", "time", "slab"):
        if not any(s == sec for s, _ in vals):
            continue
        out.append(f"[{sec}]")
        out += [f"{k} = {_toml_value(v)}" for (s, k), v in vals.items() if s == sec]
    out += ["[[objects]]", 'shape = "rectangle"', "size_m = [0.1, 0.1]",
            "translate_m = [0.0, 0.0, 0.4]"]
    return "\n".join(out) + "\n"


@SETTINGS
@given(key=st.sampled_from(sorted(GOOD_SCENE)), value=BAD_VALUES)
def test_invalid_scene_fields(tmp_path_factory, key, value):
    d = tmp_path_factory.mktemp("scene")
    if key in (("time", "start_s"), ("slab", "mu_a")) and isinstance(value, int) and \
            not isinstance(value, bool) and value == 0:
        value = -1.0  # 0 is a valid start time and a valid absorption
    (d / "s.toml").write_text(_scene_text(key, value))
    out = d / "o.h5"
    rc, err = _run(["simulate", str(d / "s.toml"), "-o", str(out)])
    _assert_clean_failure(rc, err, out)
    assert key[1] in err


@SETTINGS
@given(text=st.text(max_size=200))
def test_garbage_scene_files(tmp_path_factory, text):
    d = tmp_path_factory.mktemp("garbage")
    (d / "s.toml").write_text(text)
    out = d / "o.h5"
    rc, err = _run(["simulate", str(d / "s.toml"), "-o", str(out)])
    _assert_clean_failure(rc, err, out)


@SETTINGS
@given(kind=st.sampled_from(["shape2d", "shape4d", "nan", "negative", "complex", "strings",
                             "truncated", "no_dataset", "bad_attr", "empty"]))
def test_invalid_capture_files(tmp_path_factory, kind):
    d = tmp_path_factory.mktemp("cap")
    cap = d / "c.h5"
    arr = np.ones((8, 3, 3), np.float32)
    attrs = {"bin_width_s": 1e-11, "start_s": 0.0, "scan_width_m": 0.3}
    if kind == "shape2d":
        arr = np.ones((8, 3), np.float32)
    elif kind == "shape4d":
        arr = np.ones((2, 8, 3, 3), np.float32)
    elif kind == "nan":
        arr[2, 1, 1] = np.nan
    elif kind == "negative":
        arr[0, 0, 0] = -5
    elif kind == "complex":
        arr = arr.astype(np.complex64)
    elif kind == "empty":
        arr = np.ones((0, 3, 3), np.float32)
    elif kind == "bad_attr":
        attrs["bin_width_s"] = "fast"
    if kind == "strings":
        with h5py.File(cap, "w") as f:
            f["transient"] = np.array([b"a", b"b"])
            f.attrs.update(attrs)
    elif kind == "no_dataset":
        with h5py.File(cap, "w") as f:
            f["other"] = arr
    else:
        with h5py.File(cap, "w") as f:
            f["transient"] = arr
            f.attrs.update(attrs)
    if kind == "truncated":
        data = cap.read_bytes()
        cap.write_bytes(data[: len(data) // 3])
    out = d / "v.h5"
    rc, err = _run(["reconstruct", str(cap), "-o", str(out)])
    _assert_clean_failure(rc, err, out)


@SETTINGS
@given(row=st.lists(st.one_of(st.floats(allow_nan=True), st.text(max_size=5)), min_size=1,
                    max_size=7))
def test_invalid_brdf_csv(tmp_path_factory, row):
    d = tmp_path_factory.mktemp("csv")
    good = "30,0,30,180,0.1\n"
    line = ",".join(str(x) for x in row)
    (d / "b.csv").write_text("theta_i_deg,phi_i_deg,theta_s_deg,phi_s_deg,brdf\n" + good + line
                             + "\n" + "30,0,-5,0,0.1\n")  # always invalid: negative zenith
    out = d / "m.h5"
    rc, err = _run(["brdf", "fit", str(d / "b.csv"), "--model", "lambert", "-o", str(out)])
    _assert_clean_failure(rc, err, out)


@SETTINGS
@given(args=st.sampled_from([
    ["reconstruct"], ["reconstruct", "x.h5"], ["reconstruct", "nofile.h5", "-o", "o.h5"],
    ["simulate", "nofile.toml", "-o", "o.h5"], ["devices", "--device", "77:77", "--bogus"],
    ["brdf", "fit"], ["brdf", "texture", "nofile.h5", "-o", "t.h5"], ["frobnicate"],
    ["reconstruct", "c.h5", "-o", "o.h5", "--bins", "abc"],
    ["study", "--quick", "--full"], ["bench", "--only"],
]))
def test_invalid_cli_arguments(tmp_path_factory, args):
    d = tmp_path_factory.mktemp("cli")
    import os

    cwd = os.getcwd()
    os.chdir(d)
    try:
        rc, err = _run(args)
    finally:
        os.chdir(cwd)
    _assert_clean_failure(rc, err, d / "o.h5")
