"""How well each BRDF model reproduces measured data it has not seen (``clnlos brdf evaluate``).

For every measured set (``NAME_gonio.csv`` + ``NAME_test.csv`` in a directory):

* **interpolation**: the union of both files split at random 80/20 (numpy Generator, ``split``
  seed) over all directions; fit on 80%, score the other 20%;
* **extrapolation**: fit on ``_gonio`` and score ``_test``, whose incidence angles the fit never
  saw (the files' own split).

Scores (:func:`clnlos.brdf.fit.metrics_for`) use only samples at or above each set's significance
floor. One row per (set, mode, model, split): agreement (%), relative L2, signed peak error (%)
and fit time (s).
"""

from __future__ import annotations

import csv
import io
import json
import time
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np

from clnlos.brdf.data import BRDFSamples, read_gonio_csv
from clnlos.brdf.fit import fit_analytic, metrics_for
from clnlos.brdf.mlp import MLPConfig, train_mlp
from clnlos.checks import did_you_mean
from clnlos.errors import InputFileError, ParameterError
from clnlos.io.files import atomic_path

MODELS = ("mlp", "mlp-seed", "five-param", "torrance-sparrow")
MODES = ("interp", "extrap")
TRAIN_FRACTION = 0.8


@dataclass(frozen=True)
class EvalRow:
    material: str
    mode: str
    model: str
    split: int
    agreement_pct: float
    relative_error: float
    peak_error_pct: float
    fit_time_s: float
    train_samples: int
    test_samples: int
    floor_per_sr: float


def measured_sets(directory) -> list[str]:
    """Names ``NAME`` with both ``NAME_gonio.csv`` and ``NAME_test.csv`` in ``directory``."""
    d = Path(directory)
    if not d.is_dir():
        raise InputFileError(f"{d}: not a directory of measured BRDF sets")
    names = sorted(p.name[: -len("_gonio.csv")] for p in d.glob("*_gonio.csv")
                   if (d / (p.name[: -len("_gonio.csv")] + "_test.csv")).is_file())
    if not names:
        raise InputFileError(f"{d}: no NAME_gonio.csv with a NAME_test.csv beside it")
    return names


ROWS_JSON_MAX_BYTES = 64 << 20  # a larger JSON is not taken for a rows file of ours


def measured_files(directory) -> list[Path]:
    """Every ``NAME_gonio.csv`` and ``NAME_test.csv`` of :func:`measured_sets` (the inputs)."""
    d = Path(directory)
    return [d / f"{n}_{kind}.csv" for n in measured_sets(d) for kind in ("gonio", "test")]


def is_rows_json(path) -> bool:
    """Whether ``path`` holds the JSON rows :func:`write_rows` writes (a list of objects with
    the fields of :class:`EvalRow`), so that a rerun may replace it."""
    fields = set(EvalRow.__dataclass_fields__)
    try:
        if Path(path).stat().st_size > ROWS_JSON_MAX_BYTES:
            return False
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(doc, list) and all(isinstance(r, dict) and set(r) == fields
                                         for r in doc)


def concat(a: BRDFSamples, b: BRDFSamples) -> BRDFSamples:
    return BRDFSamples(*(np.concatenate([getattr(a, k), getattr(b, k)])
                         for k in ("theta_i", "phi_i", "theta_s", "phi_s", "brdf")),
                       meta={**a.meta, "precision": max(a.meta.get("precision", 0.0),
                                                        b.meta.get("precision", 0.0))})


def split_sets(gonio: BRDFSamples, test: BRDFSamples, mode: str, split: int):
    """(train, held-out) for ``mode`` (see the module docstring)."""
    if mode == "extrap":
        return gonio, test
    both = concat(gonio, test)
    order = np.random.default_rng(split).permutation(len(both))
    n = int(TRAIN_FRACTION * len(both))
    return both.subset(order[:n]), both.subset(order[n:])


def fit_model(name: str, train: BRDFSamples, seed: int = 0):
    """A fitted model (callable f(ti, pi, ts, ps) in 1/sr) for ``name`` in MODELS or any
    analytic model of :mod:`clnlos.brdf.fit`."""
    if name in ("mlp", "mlp-seed"):
        return train_mlp(train, MLPConfig(recipe="seed" if name == "mlp-seed" else "improved",
                                          seed=seed))[0]

    return fit_analytic(name, train, seed=seed).model


def evaluate(directory, models=MODELS, modes=MODES, splits=(0,), materials=None,
             progress=None) -> list[EvalRow]:
    names = measured_sets(directory)
    if materials:
        unmatched = [m for m in materials if not any(m in n for n in names)]
        if unmatched:  # before any fit: an empty table is not an answer
            raise ParameterError("--material", unmatched[0], "part of the name of a measured "
                                 f"set in {directory}: " + ", ".join(names)
                                 + did_you_mean(unmatched[0], names))
        names = [n for n in names if any(m in n for m in materials)]
    jobs = [(n, mode, model, s) for n in names for mode in modes for model in models
            for s in (splits if mode == "interp" else splits[:1])]
    rows = []
    cache: dict[str, tuple[BRDFSamples, BRDFSamples]] = {}
    for name, mode, model, split in progress(jobs) if progress else jobs:
        if name not in cache:
            d = Path(directory)
            cache[name] = (read_gonio_csv(d / f"{name}_gonio.csv"),
                           read_gonio_csv(d / f"{name}_test.csv"))
        train, held = split_sets(*cache[name], mode, split)
        t0 = time.perf_counter()
        fitted = fit_model(model, train, seed=split)
        dt = time.perf_counter() - t0
        m = metrics_for(fitted, train, held)
        rows.append(EvalRow(name, mode, model, split, m["test_agreement_pct"],
                            m["test_relative_error"], m["test_peak_error_pct"], dt,
                            len(train), m["test_samples"], m["test_floor_per_sr"]))
    return rows


def summary_table(rows: list[EvalRow]) -> str:
    """Markdown table: one line per (material, mode, model), mean and min over splits."""
    keys = sorted({(r.material, r.mode, r.model) for r in rows},
                  key=lambda k: (k[0], MODES.index(k[1]) if k[1] in MODES else 9,
                                 MODELS.index(k[2]) if k[2] in MODELS else 9))
    out = ["| material | mode | model | agreement % (min) | rel. L2 (max) | peak err % | "
           "fit s |", "|---|---|---|---|---|---|---|"]
    for k in keys:
        rs = [r for r in rows if (r.material, r.mode, r.model) == k]
        a = [r.agreement_pct for r in rs]
        e = [r.relative_error for r in rs]
        p = [r.peak_error_pct for r in rs]
        t = [r.fit_time_s for r in rs]
        out.append(f"| {k[0]} | {k[1]} | {k[2]} | {np.mean(a):.1f} ({min(a):.1f}) | "
                   f"{np.mean(e):.2f} ({max(e):.2f}) | {np.mean(p):+.0f} | {np.mean(t):.1f} |")
    return "\n".join(out)


def write_rows(rows: list[EvalRow], csv_path, json_path=None) -> None:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=[f.name for f in fields(EvalRow)])
    w.writeheader()
    for r in rows:
        w.writerow(asdict(r))
    with atomic_path(csv_path) as tmp:
        tmp.write_text(buf.getvalue())
    if json_path:
        with atomic_path(json_path) as tmp:
            tmp.write_text(json.dumps([asdict(r) for r in rows], indent=1))
