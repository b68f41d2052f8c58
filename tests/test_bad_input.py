"""Bad input from users (property-based): every case ends in one line naming the problem,
exit status 2, no traceback and no output file left behind."""

import contextlib
import io
import math

import h5py
import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from clnlos.app.cli import main

SETTINGS = settings(max_examples=25, deadline=None, derandomize=True,  # CI reproducible
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


# ------------------------------------------------------------------ output paths
def _capture(d):
    from clnlos.io.files import write_capture

    return write_capture(d / "c.h5", np.ones((40, 4, 4), np.float32), bin_width_s=2e-11,
                         start_s=0.0, scan_width_m=0.3)


def _snapshot(paths):
    return {p: (p.read_bytes() if p.is_file() else None) for p in paths}


@SETTINGS
@given(case=st.sampled_from(["directory", "same_as_input", "unwritable", "png_suffix",
                             "png_is_directory", "config_as_output", "parent_is_file"]))
def test_output_path_problems(tmp_path_factory, case):
    """Each ends before any work in one error line, no file left behind, inputs untouched."""
    import os

    d = tmp_path_factory.mktemp("outp")
    cap = _capture(d)
    cfg = d / "p.toml"
    cfg.write_text("[preprocess]\nmax_path_m = 1.0\n")
    out = d / "o.h5"
    args = ["reconstruct", str(cap), "-o", str(out), "--config", str(cfg)]
    leftovers = [out, out.with_suffix(".png")]
    if case == "directory":
        out.mkdir()
        leftovers = [out.with_suffix(".png")]
    elif case == "same_as_input":
        args[3] = str(cap)
        leftovers = [cap.with_suffix(".png")]
    elif case == "unwritable":
        ro = d / "ro"
        ro.mkdir()
        os.chmod(ro, 0o500)
        args[3] = str(ro / "o.h5")
        leftovers = [ro / "o.h5", ro / "o.png"]
        if os.access(ro, os.W_OK):  # root ignores permissions: use a path under a file
            args[3] = str(cap / "o.h5")
            leftovers = []
    elif case == "png_suffix":
        args[3] = str(d / "c.png")
        leftovers = [d / "c.png"]
    elif case == "png_is_directory":
        out.with_suffix(".png").mkdir()
        leftovers = [out]
    elif case == "config_as_output":
        args[3] = str(cfg)
        leftovers = []
    elif case == "parent_is_file":
        args[3] = str(cap / "sub" / "o.h5")
        leftovers = []
    inputs = [cap, cfg]
    before = _snapshot(inputs)
    rc, err = _run(args)
    assert rc == 2, err
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("clnlos: error:"), err
    for p in leftovers:
        assert not p.exists(), p
    assert _snapshot(inputs) == before
    assert not list(d.glob(".*.tmp")) and not list(d.glob("**/.*.tmp"))


@SETTINGS
@given(case=st.sampled_from(["simulate_onto_scene", "plot_onto_volume", "plot_not_png",
                             "brdf_onto_data", "study_output_is_file"]))
def test_output_paths_of_other_commands(tmp_path_factory, case):
    d = tmp_path_factory.mktemp("outo")
    scene = d / "s.toml"
    scene.write_text("[scan]\nwidth_m = 0.3\npoints = 4\n[time]\nbin_width_s = 2e-11\n"
                     "bins = 64\n[[objects]]\nshape = \"rectangle\"\n"
                     "translate_m = [0.0, 0.0, 0.4]\n")
    vol = d / "v.h5"
    with h5py.File(vol, "w") as f:
        f["volume"] = np.ones((4, 3, 3), np.float32)
    csv = d / "b.csv"
    csv.write_text("theta_i_deg,phi_i_deg,theta_s_deg,phi_s_deg,brdf\n30,0,30,180,0.1\n")
    inputs = [scene, vol, csv]
    before = _snapshot(inputs)
    args = {"simulate_onto_scene": ["simulate", str(scene), "-o", str(scene)],
            "plot_onto_volume": ["plot", str(vol), "-o", str(vol)],
            "plot_not_png": ["plot", str(vol), "-o", str(d / "p.jpg")],
            "brdf_onto_data": ["brdf", "fit", str(csv), "--model", "lambert", "-o", str(csv)],
            "study_output_is_file": ["study", "-o", str(csv)]}[case]
    rc, err = _run(args)
    assert rc == 2, err
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("clnlos: error:"), err
    assert _snapshot(inputs) == before
    assert not (d / "p.jpg").exists() and not list(d.glob(".*.tmp"))


def test_outputs_get_the_umask_mode(tmp_path):
    import os
    import stat

    cap = _capture(tmp_path)
    old = os.umask(0o022)
    try:
        assert main(["reconstruct", str(cap), "-o", str(tmp_path / "v.h5")]) == 0
    finally:
        os.umask(old)
    for p in (tmp_path / "v.h5", tmp_path / "v.png"):
        assert stat.S_IMODE(p.stat().st_mode) == 0o644, p


# ------------------------------------------------------------------ types, sanity, env, args
@SETTINGS
@given(case=st.sampled_from([
    ("scan", "width_m", '"0.3"'), ("scan", "points", "32.0"), ("scan", "points", '"32"'),
    ("time", "bins", "true"), ("time", "bin_width_s", '"2e-11"'),
    ("sampling", "density_per_m2", '"4e5"'), ("sampling", "splat_order", "1.0")]))
def test_strict_types_in_scenes(tmp_path_factory, case):
    sec, key, text = case
    d = tmp_path_factory.mktemp("types")
    base = {"scan": {"width_m": "0.3", "points": "4"},
            "time": {"bin_width_s": "2e-11", "bins": "64"},
            "sampling": {"density_per_m2": "4e4", "splat_order": "1"}}
    base[sec][key] = text
    lines = []
    for s_, kv in base.items():
        lines.append(f"[{s_}]")
        lines += [f"{k} = {v}" for k, v in kv.items()]
    lines += ["[[objects]]", 'shape = "rectangle"', "translate_m = [0.0, 0.0, 0.4]"]
    (d / "s.toml").write_text("\n".join(lines) + "\n")
    out = d / "o.h5"
    rc, err = _run(["simulate", str(d / "s.toml"), "-o", str(out)])
    _assert_clean_failure(rc, err, out)
    assert f"{sec}.{key}" in err


@SETTINGS
@given(case=st.sampled_from(["behind", "beyond_window", "before_window", "zero_capture"]))
def test_scene_sanity_and_empty_captures(tmp_path_factory, case):
    d = tmp_path_factory.mktemp("sane")
    out = d / "o.h5"
    if case == "zero_capture":
        from clnlos.io.files import write_capture

        cap = write_capture(d / "z.h5", np.zeros((40, 4, 4), np.float32), bin_width_s=2e-11,
                            start_s=0.0, scan_width_m=0.3)
        rc, err = _run(["reconstruct", str(cap), "-o", str(out)])
        _assert_clean_failure(rc, err, out)
        assert "no signal" in err
        return
    z = {"behind": -0.3, "beyond_window": 5.0, "before_window": 0.05}[case]
    start = 2e-9 if case == "before_window" else 0.0
    (d / "s.toml").write_text(f"""[scan]
width_m = 0.3
points = 4
[time]
bin_width_s = 2e-11
bins = 100
start_s = {start}
[[objects]]
shape = "rectangle"
size_m = [0.05, 0.05]
translate_m = [0.0, 0.0, {z}]
""")
    rc, err = _run(["simulate", str(d / "s.toml"), "-o", str(out)])
    _assert_clean_failure(rc, err, out)


@SETTINGS
@given(env=st.sampled_from([("CLNLOS_DEVICE", "9:9"), ("CLNLOS_DEVICE", "nosuch"),
                            ("CLNLOS_FFT", "bogus"), ("CLNLOS_THREADS", "zero"),
                            ("CLNLOS_THREADS", "-2"), ("CLNLOS_PLAN_CACHE_MB", "lots")]))
def test_bad_environment(tmp_path_factory, env):
    import os

    d = tmp_path_factory.mktemp("env")
    cap = _capture(d)
    out = d / "v.h5"
    old = os.environ.get(env[0])
    os.environ[env[0]] = env[1]
    try:
        rc, err = _run(["reconstruct", str(cap), "-o", str(out)])
    finally:
        if old is None:
            os.environ.pop(env[0])
        else:
            os.environ[env[0]] = old
    _assert_clean_failure(rc, err, out)
    assert env[0] in err or "device" in err


@SETTINGS
@given(flag=st.sampled_from(["--bin-width", "--scan-width", "--max-path", "--snr",
                             "--l1-weight", "--tv-weight", "--depth-min", "--falloff"]),
       value=st.sampled_from(["-1e-12", "-0.5", "-inf", "nan", "-3"]))
def test_negative_numbers_are_values_named_by_their_flag(tmp_path_factory, flag, value):
    d = tmp_path_factory.mktemp("neg")
    cap = _capture(d)
    out = d / "v.h5"
    rc, err = _run(["reconstruct", str(cap), "-o", str(out), flag, value])
    _assert_clean_failure(rc, err, out)
    assert flag in err, err


def test_nan_angles_are_rejected_before_the_kernel(queue):
    import pytest

    from clnlos.brdf.models import BRDFModel
    from clnlos.brdf.texture import tabulate
    from clnlos.brdf.texture_lookup import TextureLookup
    from clnlos.errors import ParameterError

    lk = TextureLookup(tabulate(BRDFModel("phong", {}), 4, 4, 4), path="buffer", queue=queue)
    with pytest.raises(ParameterError, match="angles"):
        lk(np.array([[0.1, 0.0, float("nan"), 1.0]]))


def test_sizes_beyond_the_kernel_index_range():
    import pytest

    from clnlos.errors import DeviceCapabilityError
    from clnlos.runtime.buffers import kernel_int

    assert kernel_int(2**31 - 1) == 2**31 - 1
    with pytest.raises(DeviceCapabilityError, match="32-bit"):
        kernel_int(2**31, "time bins")
