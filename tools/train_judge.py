"""Train the legibility judge that ships with clnlos (clnlos/data/legibility_judge.json) and
validate it: held out by target kind, rig and material on its twins; on every real capture
of ../shared/data (its thinning ladder, judged as a capture and as the default LCT
reconstruction), with each capture in turn left out of the one choice the real captures
make; and on mock releases (simulated captures of targets drawn apart from the twins,
written in the LCT, f-k and CDT layouts and judged through the command line with no
--model, renamed too).

    .venv/bin/python tools/train_judge.py --real-data ../shared/data

writes the judge (package data, with its provenance: commit, training set, splits, scores),
tools/results/train_judge.json (every number of docs/validation/legibility-judge.md) and
the figures tools/results/legibility_real_ladders.png and legibility_twins.png (served to
the docs as figures/). The twins
are rendered once into --cache (one .npz per twin, holding the version of the code that
rendered it); a rerun reads them back. Run from a clean checkout: the judge records the
commit it was trained at.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import io
import json
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import h5py
import numpy as np
import scipy.io

from clnlos.app.cli import main as cli
from clnlos.forward.model import ForwardModel
from clnlos.io.figures import new_figure
from clnlos.io.files import save_figure
from clnlos.io.formats.mat import lct_rect_data
from clnlos.io.outputs import provenance
from clnlos.runtime.device import get_queue
from clnlos.runtime.programs import code_digest, kernel_families
from clnlos.study.judge.apply import SHIPPED_JUDGE, judge_from
from clnlos.study.judge.features import (
    NOISE_CAPTURE_FEATURES,
    NOISE_MIP_FEATURES,
    capture_features,
    feature_matrix,
    mip_features,
    mip_of,
    pearson_r,
)
from clnlos.study.judge.heldout import BROAD_SPLITS, balanced_accuracy
from clnlos.study.judge.model import JUDGE_L2, train_judge
from clnlos.study.judge.real import (
    REAL_FRACTIONS,
    family_scores,
    judged_rows,
    ladder_views,
    real_capture_paths,
    reference_label,
)
from clnlos.study.judge.recipe import recipe_settings
from clnlos.study.judge.twins import broad_plan, render_twin, twin_scene, twin_settings
from clnlos.study.real.thinning import thinned_series

ROOT = Path(__file__).resolve().parents[1]
RENDER_MODULES = ("clnlos.forward", "clnlos.inverse", "clnlos.physics", "clnlos.operators",
                  "clnlos.brdf", "clnlos.study.judge.twins", "clnlos.study.judge.targets",
                  "clnlos.study.judge.recipe", "clnlos.study.score", "clnlos.io.capture")
ARRAYS = ("mip", "mip_halves")
BOOTSTRAP = 40          # bootstrap refits kept in the judge (its interval)
# the shipped judge's models: the features that tell an image from its noise, at even odds
# (clnlos.study.judge.model.JudgeModel.fit, clnlos.study.judge.features)
MODELS = {"capture_features": NOISE_CAPTURE_FEATURES, "volume_features": NOISE_MIP_FEATURES,
          "even_odds": True}
PER_KIND = 70           # twins per target kind
MOCK_FRACTIONS = (1.0, 0.1, 0.01, 1e-3, 1e-4, 1e-5)
LABEL = ("legible: the rung's reconstruction agrees with its twin's full-photon one (Pearson "
         "r >= 0.8 of the MIPs) where that one shows the target (glyphs and charts: the "
         "template rule and IoU above the box baseline; any other target: its match with "
         "its ideal image at least 0.75 and above its filled box's); twins whose full-photon "
         "image does not show their target are left out: clnlos.study.judge.twins")


# ------------------------------------------------------------------ twins
def render_version() -> str:
    """A digest of the code that renders a twin (its rows' images)."""
    return code_digest(RENDER_MODULES, kernel_families())[:16]


def cached_rows(entry: dict, cache: Path, version: str, device=None) -> list[dict]:
    """:func:`render_twin` of ``entry`` with its MIPs, read from / written to ``cache`` (one
    .npz per twin, named by the twin and the twins' settings, holding the code ``version``
    that rendered it: another version renders it again)."""
    blob = json.dumps({"entry": entry, "twins": twin_settings()}, sort_keys=True)
    path = cache / f"twin-{hashlib.sha1(blob.encode()).hexdigest()}.npz"
    if path.is_file():
        with np.load(path, allow_pickle=False) as z:
            if str(z["version"]) == version:
                rows = json.loads(str(z["rows"]))
                for k in ARRAYS:
                    for r, a in zip(rows, z[k], strict=True):
                        r[k] = a
                return rows
    rows = render_twin(entry, device=device, keep_mips=True)
    meta = [{k: v for k, v in r.items() if k not in ARRAYS} for r in rows]
    cache.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, rows=json.dumps(meta), version=version,
             **{k: np.stack([r[k] for r in rows]) for k in ARRAYS})
    tmp.replace(path)
    return rows


def render_plan(plan: list[dict], cache: Path, version: str | None = None,
                device=None) -> list[dict]:
    """Every twin's rows (each with its plan index ``scene``; its features measured again
    on its MIPs: the features' code is today's), ``version`` the code version the cache
    must hold (default :func:`render_version`)."""
    version = version or render_version()
    rows, t0 = [], time.perf_counter()
    for k, e in enumerate(plan):
        for r in cached_rows(e, cache, version, device):
            f = (mip_features(r["mip"]) if r.get("volume_only")
                 else capture_features(r["mip"], *r["mip_halves"]))
            rows.append({**r, "scene": k, "features": f})
        if (k + 1) % 50 == 0 or k + 1 == len(plan):
            print(f"twins {k + 1}/{len(plan)} {time.perf_counter() - t0:.0f} s", flush=True)
    return rows


FIDELITY_CUTS = (0.6, 0.7, 0.75, 0.8, 0.85)


def glyph_rule_agreement(rows: list[dict]) -> dict:
    """How the fidelity rule of the other kinds reproduces the study's label on the glyph
    and chart twins (their rungs by the target, ``legible_truth``): balanced accuracy of
    ``faithful`` (the rule at FIDELITY_NCC) against it, and of the rule at other cuts of
    the match (FIDELITY_CUTS)."""
    g = [r for r in rows if r["kind"] in ("glyph", "chart") and "view" not in r]
    y = np.array([r["legible_truth"] for r in g], bool)
    match, box = (np.array([r[k] for r in g]) for k in ("match", "match_box"))
    return {"n": len(g), "legible": int(y.sum()),
            "balanced_accuracy": balanced_accuracy(y, np.array([r["faithful"] for r in g])),
            "cuts": {str(c): balanced_accuracy(y, (match >= c) & (match > box))
                     for c in FIDELITY_CUTS}}


def training_set(plan: list[dict], rows: list[dict]) -> dict:
    """What the judge learnt from: counts per kind, rig, material and label."""
    base = [r for r in rows if "view" not in r]

    def count(key):
        out = {}
        for r in base:
            k = str(r[key])
            c = out.setdefault(k, {"rungs": 0, "legible": 0})
            c["rungs"] += 1
            c["legible"] += int(bool(r["legible"]))
        return out

    return {"scenes": len(plan), "rungs": len(base), "rows_with_gain_views": len(rows),
            "legible": int(sum(bool(r["legible"]) for r in base)),
            "by_kind": count("kind"), "by_rig": count("rig_group"),
            "by_material": count("material")}


# ------------------------------------------------------------------ real captures
def real_views(root: Path, device=None) -> list[dict]:
    """Every real capture's thinning ladder as any judge reads it: its reconstructions with
    the recipe and by default (:func:`clnlos.study.judge.real.ladder_views`)."""
    rows = []
    for fam, path in real_capture_paths(root):
        rows += ladder_views(path, REAL_FRACTIONS, device=device, family=fam,
                             default_volumes=True)
    return rows


def real_scores(views: list[dict], judge) -> tuple[list[dict], dict, dict]:
    """The views judged, and the scores of the capture model (P) and of the volume model on
    the default reconstructions (P_default, against their own reference labels)."""
    rows = judged_rows(views, judge)
    as_default = [{**r, "p_legible": r["p_default"], "reference": r["reference_default"]}
                  for r in rows]
    return rows, family_scores(rows), family_scores(as_default)


# ------------------------------------------------------------------ mock releases
MOCKS = (
    # name, layout, target (kind, seed), material, scan width (m), depth (m), points,
    # bin width (s), bins, photons per scan point (the hidden side's; the LCT release holds
    # 700-2900 after its direct cut), floor over signal
    ("exit_sign", "lct", ("sign", 101), "retroreflective", 0.8, 0.75, 64, 4e-12, 2048,
     1500.0, 0.3),
    ("mannequin", "lct", ("figure", 202), "standard white plate", 0.8, 0.7, 64, 4e-12, 2048,
     1500.0, 0.3),
    ("statue", "fk", ("shape3d", 303), "standard white plate", 1.0, 1.0, 64, 32e-12, 512,
     2000.0, 0.5),
    ("dragon", "fk", ("object", 404), "cement board", 1.0, 1.1, 64, 32e-12, 512, 2000.0,
     0.5),
    ("figure_behind_slab", "cdt", ("figure", 505), "standard white plate", 0.7, 0.5, 32,
     16e-12, 512, 2e5, 0.1),
)


def mock_entry(m) -> dict:
    name, layout, (kind, seed), material, width, depth, points, bw, bins, ppp, floor = m
    return {"kind": kind, "rig": "slab" if layout == "cdt" else "none", "rig_group": "mock",
            "family": layout, "material": material, "scan_width_m": width, "depth_m": depth,
            "points": points, "bin_width_s": bw, "pulse_s": 60e-12, "photons_per_point": ppp,
            "background": floor, "glyph": kind, "side_m": 0.85 * width, "offset_m": [0, 0],
            "seed": seed, "bins": bins, "name": name, "layout": layout}


def mock_counts(entry: dict, device=None) -> tuple[np.ndarray, str]:
    """Poisson counts [t, y, x] of a mock release (its window ``bins`` long, a direct
    reflection in its first bins for the LCT layout) and its target's name."""
    with tempfile.TemporaryDirectory() as d:
        scene, _, name = twin_scene(entry, Path(d))
        scene = replace(scene, bins=entry["bins"])
        mu = np.asarray(ForwardModel(scene, queue=get_queue(device)).capture().transient,
                        np.float64)
    n = entry["photons_per_point"] * entry["points"] ** 2
    mu *= n / max(mu.sum(), 1e-300)
    mu += entry["background"] * n / mu.size
    if entry["layout"] == "lct":  # the wall's own reflection: 15 times the rest, as released
        mu[:8] += 15 * n / (8 * entry["points"] ** 2)
    return np.random.default_rng(entry["seed"]).poisson(mu).astype(np.float64), name


def write_mock(counts: np.ndarray, entry: dict, path: Path) -> None:
    """The counts in the release layout of ``entry["layout"]``: LCT (rect_data, width),
    f-k (meas (y, x, t) rows running down, tofgrid zeros: MATLAB v5) or CDT (meas (t, y
    down, x), MATLAB v7.3)."""
    if entry["layout"] == "lct":
        scipy.io.savemat(path, {"rect_data": lct_rect_data(counts).astype(np.uint16),
                                "width": entry["scan_width_m"] / 2})
    elif entry["layout"] == "fk":
        scipy.io.savemat(path, {"meas": np.transpose(counts, (1, 2, 0))[::-1],
                                "tofgrid": np.zeros(counts.shape[1:])})
    else:
        with h5py.File(path, "w") as f:
            f["meas"] = np.transpose(counts[:, ::-1, :])


def mock_options(entry: dict) -> list[str]:
    """The flags a user gives for a layout that does not store its geometry."""
    if entry["layout"] == "fk":
        return ["--scan-width", str(entry["scan_width_m"])]
    if entry["layout"] == "cdt":
        return ["--scan-width", str(entry["scan_width_m"]), "--slab-thickness", "0.0254",
                "--mu-a", "0.53", "--mu-s-prime", "262", "--n", "1.12"]
    return []


def run_cli(argv: list[str]) -> tuple[int, str]:
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        rc = cli(argv)
    return rc, out.getvalue()


def judged(path: Path, options: list[str]) -> dict:
    """``clnlos legibility PATH --json`` (the shipped judge, no --model)."""
    rc, out = run_cli(["legibility", str(path), "--json", *options])
    if rc:
        raise RuntimeError(f"clnlos legibility {path} exited {rc}")
    return json.loads(out.strip().splitlines()[-1])


def mock_releases(folder: Path, device=None, model: Path | None = None) -> list[dict]:
    """Every mock's ladder through the command line: the capture file judged, its default
    reconstruction (``clnlos reconstruct``) judged, the full capture judged again under the
    name of a shared capture; the reference: the default reconstruction's MIP against the
    full-photon one's. ``model``: another judge (``--model``) instead of the shipped one."""
    rows = []
    judge_opts = [] if model is None else ["--model", str(model)]
    for m in MOCKS:
        e = mock_entry(m)
        t0 = time.perf_counter()
        counts, target = mock_counts(e, device)
        opts = mock_options(e)
        first = None
        for f, c in zip(MOCK_FRACTIONS, thinned_series(counts, MOCK_FRACTIONS, 57),
                        strict=True):
            path = folder / f"{e['name']}_{f:g}.mat"
            write_mock(c, e, path)
            cap = judged(path, opts + judge_opts)
            vol = folder / f"{e['name']}_{f:g}.h5"
            rc, _ = run_cli(["reconstruct", str(path), "-o", str(vol), *opts, "--force"])
            if rc:
                raise RuntimeError(f"clnlos reconstruct {path} exited {rc}")
            with h5py.File(vol, "r") as h:
                mip = mip_of(h["volume"][()])
            first = mip if first is None else first
            agree = pearson_r(mip, first)
            v = judged(vol, judge_opts)
            row = {"mock": e["name"], "layout": e["layout"], "target": target,
                   "fraction": f, "photons": float(c.sum()), "p_capture": cap["p_legible"],
                   "interval_capture": cap["interval"], "notes_capture": cap["notes"],
                   "p_default": v["p_legible"], "interval_default": v["interval"],
                   "notes_default": v["notes"], "agreement_default": agree,
                   "reference": reference_label(agree), "mip": mip}
            if f == 1.0:  # the same file under a shared capture's name
                renamed = folder / "letters_ut.mat"
                shutil.copy(path, renamed)
                row["p_capture_renamed"] = judged(renamed, opts + judge_opts)["p_legible"]
            rows.append(row)
        print(f"mock {e['name']}: {time.perf_counter() - t0:.0f} s", flush=True)
    return rows


# ------------------------------------------------------------------ leave one capture out
L2_CHOICES = (0.1, 0.3, 1.0, 3.0, 10.0)


def capture_bar(rows: list[dict]) -> tuple[int, float]:
    """How a judge's verdicts on one capture's ladder meet the bar: (passes, margin).
    Passes: P >= 0.8 at full photons and P < 0.5 on every rung whose image is gone, both as
    a capture and as its default reconstruction; margin: the least of P - 0.8 at full
    photons and 0.5 - P where gone (for ties)."""
    full = rows[0]
    m = [full["p_legible"] - 0.8, full["p_default"] - 0.8]
    m += [0.5 - r["p_legible"] for r in rows if r["reference"] == "gone"]
    m += [0.5 - r["p_default"] for r in rows if r["reference_default"] == "gone"]
    return int(min(m) >= 0), float(min(m))


def choose_l2(judges: dict, views: list[dict], captures) -> float:
    """The L2 weight whose judge passes the bar (:func:`capture_bar`) on the most of
    ``captures``, ties to the larger sum of margins."""
    def score(l2):
        bars = [capture_bar(judged_rows([v for v in views if v["capture"] == c], judges[l2]))
                for c in captures]
        return (sum(b[0] for b in bars), sum(b[1] for b in bars))
    return max(judges, key=score)


def loco(rows: list[dict], views: list[dict], seed: int) -> dict:
    """The one choice the real captures make: the judges' L2 weight among L2_CHOICES (the
    weights' prior, JUDGE_L2 by default), chosen where the judge passes the bar on the most
    captures. Left out in turn: each capture's weight is chosen on the other captures and
    its ladder judged by that judge, so that no capture tunes the rule it is tested on."""
    judges = {l2: train_judge(rows, recipe_settings(), splits=BROAD_SPLITS, seed=seed,
                              l2=l2, **MODELS)[0] for l2 in L2_CHOICES}
    names = list(dict.fromkeys(v["capture"] for v in views))
    out = {"choices": list(L2_CHOICES), "chosen_on_all": choose_l2(judges, views, names),
           "captures": {}}
    for c in names:
        l2 = choose_l2(judges, views, [n for n in names if n != c])
        got = judged_rows([v for v in views if v["capture"] == c], judges[l2])
        out["captures"][c] = {"l2": l2, "passes": bool(capture_bar(got)[0]),
                              "p": [r["p_legible"] for r in got],
                              "p_default": [r["p_default"] for r in got],
                              "reference": [r["reference"] for r in got],
                              "reference_default": [r["reference_default"] for r in got]}
    return out


# ------------------------------------------------------------------ another judge
def compare(other, rows: list[dict], views: list[dict], mocks: bool) -> dict:
    """Another judge (a study's judge.json: the one before the shipped judge) on the same
    twins (every decided rung; it saw none of them), real ladders and mock releases."""
    base = [r for r in rows if r["legible"] is not None and r.get("view") != "ramp"]
    out = {"source": other.info.get("source"), "twins": {}}
    for name, sel in (("capture", [r for r in base if not r.get("volume_only")]),
                      ("volume", base)):
        model = other.model(name)
        y = np.array([bool(r["legible"]) for r in sel])
        p = model.predict_proba(feature_matrix([r["features"] for r in sel], model.features))
        out["twins"][name] = {"all": balanced_accuracy(y, p >= 0.5), "by_kind": {
            k: balanced_accuracy(y[[r["kind"] == k for r in sel]],
                                 p[[r["kind"] == k for r in sel]] >= 0.5)
            for k in dict.fromkeys(r["kind"] for r in sel)}}
    if views:
        real_rows, scores, scores_default = real_scores(views, other)
        out["real"] = {"rows": [{k: v for k, v in r.items() if not k.startswith("mip")}
                                for r in real_rows],
                       "capture": scores, "default_volume": scores_default}
    if mocks:
        with tempfile.TemporaryDirectory() as d:
            got = mock_releases(Path(d), model=Path(other.info["source"]))
        out["mocks"] = [{k: v for k, v in r.items() if k != "mip"} for r in got]
    return out


# ------------------------------------------------------------------ figures
def ladders_figure(real_rows: list[dict]):
    """Per real capture its MIPs along the thinning ladder (the judge's reconstruction) and
    beside them its P(legible) against photons, as a capture (solid) and as the default
    LCT reconstruction (dashed), and the MIP's agreement with the full-photon one's."""
    names = list(dict.fromkeys(r["capture"] for r in real_rows if "error" not in r))
    show = (1.0, 0.03, 3e-3, 1e-4)
    fig, ax = new_figure(len(names), len(show) + 1,
                         (2.0 * (len(show) + 1) + 2.0, 2.1 * len(names)))
    ax = np.asarray(ax).reshape(len(names), len(show) + 1)
    for i, n in enumerate(names):
        rs = [r for r in real_rows if r.get("capture") == n]
        for j, f in enumerate(show):
            a = ax[i, j]
            r = next(r for r in rs if abs(r["fraction"] - f) < 1e-12)
            a.imshow(r["mip"], origin="lower", cmap="gray", vmin=0, vmax=1)
            a.set_xticks([])
            a.set_yticks([])
            a.set_title(f"{n[:20]} x{f:g}\nP {r['p_legible']:.2f} / {r['p_default']:.2f} "
                        f"r {r['agreement']:.2f}", fontsize=7)
        c = ax[i, -1]
        c.semilogx([r["photons"] for r in rs], [r["p_legible"] for r in rs], "o-",
                   label="capture")
        c.semilogx([r["photons"] for r in rs], [r["p_default"] for r in rs], "s--",
                   label="default LCT volume")
        c.semilogx([r["photons"] for r in rs], [r["agreement"] for r in rs], ":",
                   color="gray", label="r with full photons")
        c.axhline(0.8, color="tab:green", lw=0.5)
        c.axhline(0.5, color="tab:red", lw=0.5)
        c.set(ylim=(-0.05, 1.05), xlabel="photons", ylabel="P(legible)")
        c.tick_params(labelsize=7)
        if i == 0:
            c.legend(fontsize=6)
    return fig


def twins_figure(plan: list[dict], rows: list[dict], per_kind: int = 4):
    """A few twins of every kind at the top of their ladder and two rungs down, labelled
    (undecided: the top rung does not show the target)."""
    kinds = list(dict.fromkeys(e["kind"] for e in plan))
    fig, ax = new_figure(len(kinds), 3 * per_kind, (1.3 * 3 * per_kind, 1.5 * len(kinds)))
    ax = np.asarray(ax).reshape(len(kinds), 3 * per_kind)
    for i, k in enumerate(kinds):
        scenes = [s for s, e in enumerate(plan) if e["kind"] == k][:per_kind]
        for j, s in enumerate(scenes):
            rs = [r for r in rows if r["scene"] == s and "view" not in r]
            for q, r in enumerate(rs[:3]):
                a = ax[i, 3 * j + q]
                a.imshow(r["mip"], origin="lower", cmap="gray")
                a.set_xticks([])
                a.set_yticks([])
                word = {True: "legible", False: "not", None: "undecided"}[r["legible"]]
                a.set_title(f"{r['target'][:16]}\n{word} {r['photons_per_point']:.2g}/pt",
                            fontsize=6)
    return fig


# ------------------------------------------------------------------ main
def git_state() -> dict:
    def git(*a):
        return subprocess.run(["git", *a], cwd=ROOT, capture_output=True, text=True).stdout

    return {"commit": git("rev-parse", "HEAD").strip(),
            "dirty": bool(git("status", "--porcelain", "--untracked-files=no").strip())}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--per-kind", type=int, default=PER_KIND)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--real-data", type=Path, default=None)
    ap.add_argument("--cache", type=Path, default=ROOT / "out" / "judge_twins")
    ap.add_argument("--cache-version", default=None,
                    help="the code version the cached twins must hold (default: the digest "
                         "of the code that renders them)")
    ap.add_argument("--judge", type=Path,
                    default=ROOT / "clnlos" / "data" / SHIPPED_JUDGE)
    ap.add_argument("--out", type=Path, default=ROOT / "tools" / "results" / "train_judge")
    ap.add_argument("--figures", type=Path, default=ROOT / "tools" / "results")
    ap.add_argument("--render-only", action="store_true")
    ap.add_argument("--no-mocks", action="store_true")
    ap.add_argument("--compare", type=Path, default=None,
                    help="another judge (a study folder or its judge.json) measured on the "
                         "same twins, real ladders and mocks (results' \"compare\")")
    args = ap.parse_args(argv)
    t0 = time.process_time()
    plan = broad_plan(args.per_kind, seed=args.seed)
    rows = render_plan(plan, args.cache, args.cache_version)
    if args.render_only:
        return 0
    t0b = time.process_time()
    views = real_views(args.real_data) if args.real_data is not None else []
    t1 = time.process_time()
    held_out = loco(rows, views, args.seed) if views else None
    l2 = held_out["chosen_on_all"] if held_out else JUDGE_L2
    judge, validation = train_judge(rows, recipe_settings(), splits=BROAD_SPLITS,
                                    bootstrap=BOOTSTRAP, seed=args.seed, l2=l2, **MODELS)
    t2 = time.process_time()
    result = {"provenance": {**provenance(), **git_state(),
                             "command": "python tools/train_judge.py " + " ".join(
                                 sys.argv[1:] if argv is None else argv)},
              "training_set": training_set(plan, rows),
              "glyph_rule_agreement": glyph_rule_agreement(rows),
              "l2": l2, "splits": {m: validation[m][0] for m in validation},
              "split_details": {m: validation[m][1] for m in validation},
              "leave_one_capture_out": held_out,
              "cost_s": {"twins_cpu": t0b - t0, "real_views_cpu": t1 - t0b,
                         "training_cpu": t2 - t1}}
    judge.info.update(provenance=result["provenance"], training_set=result["training_set"],
                      twins={**twin_settings(), "per_kind": args.per_kind, "seed": args.seed},
                      splits=result["splits"], label=LABEL)
    args.judge.write_text(json.dumps(judge.to_json(), separators=(",", ":")))
    print("splits", json.dumps(result["splits"], indent=1))
    if views:
        real_rows, scores, scores_default = real_scores(views, judge)
        result["real"] = {"rows": [{k: v for k, v in r.items() if not k.startswith("mip")}
                                   for r in real_rows],
                          "capture": scores, "default_volume": scores_default}
        save_figure(ladders_figure(real_rows), args.figures / "legibility_real_ladders.png")
    if not args.no_mocks:
        with tempfile.TemporaryDirectory() as d:
            mocks = mock_releases(Path(d))
        result["mocks"] = [{k: v for k, v in r.items() if k != "mip"} for r in mocks]
    if args.compare is not None:
        result["compare"] = compare(judge_from(args.compare), rows, views, not args.no_mocks)
    save_figure(twins_figure(plan, rows), args.figures / "legibility_twins.png")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(json.dumps(result, indent=1, default=float))
    print(f"wrote {args.judge}, {args.out.with_suffix('.json')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
