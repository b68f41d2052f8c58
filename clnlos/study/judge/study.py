"""The study's legibility judge: twins rendered (cached), the judge trained and validated
(held out by glyph, geometry and material; by family on the real captures), written beside
results.json as judge.json (:mod:`clnlos.study.judge.model`, :mod:`clnlos.study.judge.twins`,
:mod:`clnlos.study.judge.real`).

The capture model's training set is the twins alone (its features need the photon halves);
the volume model's adds every glyph reconstruction of the study with ground truth (every
method and inversion the study ran, its MIP's features and the same label), grouped by its
glyph, geometry and material as the twins are.
"""

from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path

from clnlos.io.files import atomic_path
from clnlos.io.outputs import provenance, stamp
from clnlos.study.samples.render import code_version
from clnlos.study.judge.heldout import geometry_key
from clnlos.study.judge.model import JUDGE_FILE, JUDGE_FOLDS, train_judge
from clnlos.study.judge.features import MIP_FEATURES, mip_features
from clnlos.study.judge.real import family_scores, family_split
from clnlos.study.judge.twins import TwinGrid, render_twin, twin_plan, twin_settings

LABEL = ("legible: identified by the template rule and IoU above the box baseline "
         "(simulations); real captures: agreement with the full-photon MIP (reference, "
         "testing only)")


def study_volume_rows(pairs) -> list[dict]:
    """The volume model's extra rows: every distinct (sample, result) with ground truth."""
    rows, seen = [], set()
    for s, r in pairs:
        if "identified" not in r:
            continue
        key = json.dumps(s, sort_keys=True)
        if key in seen:
            continue
        seen.add(key)
        rows.append({"glyph": s["text"], "geometry": geometry_key(s),
                     "material": s["material"], "features": mip_features(r["mip"]),
                     "legible": bool(r["identified"]) and r["iou"] > r["iou_box_baseline"]})
    return rows


def cached_twin(entry: dict, grid: TwinGrid, cache: Path | None, version: str,
                device=None) -> list[dict]:
    """:func:`clnlos.study.judge.twins.render_twin` of ``entry``, read from / written to
    ``cache`` (JSON keyed by the entry, the grid, the twins' settings and the code)."""
    if cache is None:
        return render_twin(entry, grid, device=device)
    blob = json.dumps({"entry": entry, "twins": twin_settings(grid), "code": version,
                       "kind": "judge_twin"}, sort_keys=True)
    path = cache / f"twin-{hashlib.sha1(blob.encode()).hexdigest()}.json"
    if path.is_file():
        try:
            return json.loads(path.read_text())
        except (OSError, ValueError):
            path.unlink(missing_ok=True)
    rows = render_twin(entry, grid, device=device)
    cache.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(rows))
    return rows


def study_judge(pairs, out_dir: Path, *, per_geometry: int, seed: int = 0,
                cache: Path | None = None, real_root: Path | None = None, device=None,
                progress=None) -> tuple[object, dict, dict, list[dict]]:
    """Train, validate and save the judge. Returns (the judge, results.json
    ``classifier`` without ``real_thinning``: ``splits`` (the capture model's),
    ``volume_splits`` and ``family``; results.json ``judge``: the details and the cost; the
    family split's rows with their MIPs, for the report)."""
    cpu0, wall0 = time.process_time(), time.perf_counter()
    grid = TwinGrid()
    plan = twin_plan(per_geometry=per_geometry, seed=seed)
    version = code_version() if cache is not None else ""
    rows = []
    for k, entry in enumerate(plan):
        rows += cached_twin(entry, grid, cache, version, device)
        if progress is not None:
            progress(k + 1, len(plan))
    cpu1 = time.process_time()
    judge, validation = train_judge(rows, twin_settings(grid), study_volume_rows(pairs),
                                    seed=seed)
    cpu2 = time.process_time()
    family = family_split(real_root, judge, device=device) if real_root is not None else []
    cpu3 = time.process_time()
    judge.info["label"] = LABEL
    judge.info["provenance"] = {**provenance(), "command": "clnlos study"}
    with atomic_path(out_dir / JUDGE_FILE) as tmp:
        tmp.write_text(json.dumps(stamp(judge.to_json()), indent=1))
    classifier = {"splits": validation["capture"][0],
                  "volume_splits": validation["volume"][0],
                  "family": {"rows": [{k: v for k, v in r.items() if k != "mip"}
                                      for r in family],
                             **(family_scores(family) if family else {"captures": {}})}}
    details = {"label": LABEL, "model": "logistic regression on standardised measured "
               "features (class-balanced, prior log-odds restored)",
               "file": JUDGE_FILE, "capture_features": list(judge.capture.features),
               "volume_features": list(MIP_FEATURES), "split_folds": dict(JUDGE_FOLDS),
               "n": int(len(rows)), "legible": int(sum(r["legible"] for r in rows)),
               "n_volume": judge.info["n_volume"], "twins": {**twin_settings(grid),
                                                             "scenes": len(plan)},
               "splits": validation["capture"][1], "volume_splits": validation["volume"][1],
               "cost_s": {"twins_cpu": cpu1 - cpu0, "training_cpu": cpu2 - cpu1,
                          "family_cpu": cpu3 - cpu2,
                          "wall": time.perf_counter() - wall0}}
    return judge, classifier, details, family
