"""The study file (clnlos.study.file.spec, ``clnlos study STUDY.toml``): the built-in studies
are study files; a bad file ends in one line naming the key and its value, exit 2, before any
work; the plan a file asks for (the inversions a method cannot run left out with a note)."""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from clnlos.app.cli import main
from clnlos.errors import ClnlosError
from clnlos.study.file.spec import builtin_text, load_study, parse_study
from clnlos.study.plan.entries import study_plan
from clnlos.study.samples.materials import prepare_materials

RIG = {"scan": {"width_m": 0.4, "points": 12}, "time": {"bin_width_s": 32e-12},
       "laser": {"pulse_width_s": 60e-12},
       "detector": {"power_w": 0.4, "exposure_s": 1e-3, "etendue_m2_sr": 1e-8,
                    "dark_count_rate_hz": 100.0}}
GOOD = {**RIG, "study": {"realisations": 2},
        "inversions": {"methods": ["lct", "iterative"],
                       "reflectance": ["lambertian", "known"]},
        "materials": [{"name": "paint", "brdf": "glossy-paint"},
                      {"name": "paint, dark", "brdf": "glossy-paint", "albedo": 0.3},
                      {"brdf": "retroreflective"}],
        "targets": [{"text": "E", "height_m": 0.2, "depth_m": 0.6}],
        "sweep": {"exposure_s": [1e-5, 1e-3]}}


def _toml(d: dict) -> str:
    """A study dict as TOML (tables, arrays of tables, strings, numbers, lists)."""
    def val(v):
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, list):
            return "[" + ", ".join(val(x) for x in v) + "]"
        return repr(v)

    out = []
    for k, v in d.items():
        if isinstance(v, dict):
            out.append(f"[{k}]")
            out += [f"{a} = {val(b)}" for a, b in v.items()]
        elif isinstance(v, list) and v and isinstance(v[0], dict):
            for t in v:
                out.append(f"[[{k}]]")
                out += [f"{a} = {val(b)}" for a, b in t.items()]
        else:
            out.insert(0, f"{k} = {val(v)}")
    return "\n".join(out) + "\n"


def test_builtin_studies_are_study_files_written_out_as_they_run(tmp_path, capsys):
    """--quick and --full load the shipped files; --init writes them (or the planner's
    template) and the written file, run by path, is the same study (same seeds, same plan)."""
    for flag, name in (("--quick", "quick"), ("--full", "full"), (None, "template")):
        out = tmp_path / f"{name}.toml"
        assert main(["study", "--init", str(out), *([flag] if flag else [])]) == 0
        assert out.read_text() == builtin_text(name)
        by_path, built = load_study(out), load_study(name)
        same = {f.name for f in dataclasses.fields(built)} - {"source", "text", "name"}
        assert all(getattr(by_path, f) == getattr(built, f) for f in same), name
    assert main(["study", "--init", str(tmp_path / "quick.toml")]) == 2  # never over a file
    assert "exists" in capsys.readouterr().err
    quick = load_study("quick")
    assert [m.name for m in quick.materials][:2] == ["gold-plated polyester film",
                                                     "quartz glass"]
    assert {t.name for t in quick.targets} == {"seed_table1", "legible"}
    assert quick.table.legible_target == "legible" and quick.judge_twins == 16
    assert load_study("full").transport is not None and load_study("quick").transport is None


def test_the_template_plans_what_its_comments_say(tmp_path):
    s = load_study("template")
    assert s.table is None and s.grid.slab is None
    assert len({m.brdf for m in s.materials}) == 1 and len(s.materials) == 2
    assert any("exposure_s" in sw.variables for sw in s.sweeps)
    mats, _ = prepare_materials(s, tmp_path)
    plan, _ = study_plan(s, mats)
    assert {(m["method"], m["inversion"]) for m, _ in plan} >= {("lct", "lambertian"),
                                                                ("iterative", "lambertian")}


def test_a_method_that_cannot_assume_a_lobe_is_left_out_with_a_note(tmp_path):
    s = parse_study(GOOD)
    mats, _ = prepare_materials(s, tmp_path)
    plan, notes = study_plan(s, mats)
    invs = {(m["material"], m["method"], m["inversion"]) for m, _ in plan}
    assert ("paint", "lct", "known") not in invs and ("paint", "iterative", "known") in invs
    assert ("retroreflective", "lct", "known") in invs  # LCT's (t/T)^2 falloff
    assert any("lct" in n and "glossy" in n for n in notes)
    # one noise stream per target, letter and realisation: every material and exposure
    # of realisation k meets the same seed
    seeds = {(m["k"], s_["seed"]) for m, s_ in plan}
    assert len(seeds) == 2
    dark = [s_ for m, s_ in plan if m["material"] == "paint, dark"]
    assert all(s_["albedo"] == 0.3 for s_ in dark)


BAD = [
    (lambda d: d.update(colour="red"), "colour"),
    (lambda d: d["materials"][0].update(brdf="unobtainium"), r"materials\[0\].brdf"),
    (lambda d: d["materials"][0].update(brdf="missing.csv"),
     r"materials\[0\].brdf.*no such BRDF file$"),
    (lambda d: d["sweep"].update(exposure_s=[-1e-3, 1e-3]), "sweep.exposure_s"),
    (lambda d: d["sweep"].update(exposure_s=[]), "sweep.exposure_s"),
    (lambda d: d.update(targets=[{"mask": "missing.png", "width_m": 0.2, "depth_m": 1.0}]),
     r"targets\[0\].mask"),
    (lambda d: d.update(targets=[{"mask": "dark.png", "width_m": 0.2, "depth_m": 1.0}]),
     "no shape"),
    (lambda d: d.update(targets=[{"mask": "garbage.png", "width_m": 0.2, "depth_m": 1.0}]),
     r"targets\[0\].mask: .*garbage.png: unreadable"),
    (lambda d: d["targets"][0].pop("depth_m"), r"targets\[0\].depth_m"),
    (lambda d: d["targets"][0].update(text="E!"), r"targets\[0\].text"),
    (lambda d: d["inversions"].update(methods=["backprojection"]), "inversions.methods"),
    (lambda d: d["inversions"].update(reflectance=["shiny"]), "inversions.reflectance"),
    (lambda d: d["materials"].append({"name": "paint", "brdf": "lambertian"}),
     r"materials\[3\].name"),
    (lambda d: d.update(sweep={"slab_thickness_m": [0.0, 0.01]}), "slab_thickness_m"),
    (lambda d: d.update(real=[{"capture": "none.mat", "material": "paint"}]),
     r"real\[0\].capture"),
    (lambda d: d["study"].update(realisations=0), "study.realisations"),
    (lambda d: d["scan"].update(points=0), "scan.points"),
    (lambda d: d.pop("sweep"), "sweep"),
]


@pytest.mark.parametrize("mutate,field", BAD)
def test_a_bad_study_file_is_one_line_exit_2_before_any_work(tmp_path, capsys, mutate,
                                                              field):
    from PIL import Image

    Image.fromarray(np.zeros((8, 8), np.uint8)).save(tmp_path / "dark.png")
    (tmp_path / "garbage.png").write_text("not an image")
    d = json.loads(json.dumps(GOOD))
    mutate(d)
    path = tmp_path / "bad.toml"
    path.write_text(_toml(d))
    out = tmp_path / "out"
    assert main(["study", str(path), "-o", str(out), "--workers", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("clnlos: error:"), err
    assert "bad.toml" in err[0]
    import re

    assert re.search(field, err[0]), err[0]
    assert not out.exists()  # nothing was started


def test_study_from_python_takes_a_dict_and_checks_it():
    import clnlos

    with pytest.raises(ClnlosError, match="materials"):
        clnlos.study({**GOOD, "materials": []}, "out/never")
    assert callable(clnlos.study) and clnlos.study.run is not None
    assert not Path("out/never").exists()
