"""Write tools/results/INDEX.md: every committed result file, the command that produces it,
the commit that last changed its content (git, renames followed) and whether it is current
or superseded. tests/test_results_index.py fails on a file the index does not list and on a
listed file that is gone.

    .venv/bin/python tools/results_index.py
"""

from __future__ import annotations

import fnmatch
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "tools" / "results"
INDEX = RESULTS / "INDEX.md"

# (glob under tools/results, command that writes it, status, what it is / where it is read)
ENTRIES: tuple[tuple[str, str, str, str], ...] = (
    ("bench.json", "clnlos bench --quick -o tools/results", "current",
     "every kernel knob against its cost (docs/benchmarks.md)"),
    ("bench.html", "clnlos bench --quick -o tools/results", "current",
     "its Pareto plots and recommended settings"),
    ("cold_memory.json", "python tools/cold_memory.py -o tools/results/cold_memory.json",
     "current", "the cold 128 x 128 x 512 photon-count LCT and f-k: FFT pairs, CPU s, peak "
     "RSS per stage (docs/performance.md)"),
    ("cold_memory_before.json", "python tools/cold_memory.py --code DIR --code-label ... "
     "(DIR: git archive 236ca5d)", "superseded",
     "the same before issue 49's memory cuts (docs/performance.md)"),
    ("cold_memory_noise_free.json", "python tools/cold_memory.py --noise-free -o ...",
     "current", "the same capture noise-free"),
    ("cold_memory_noise_free_before.json", "python tools/cold_memory.py --noise-free --code "
     "DIR ... (DIR: git archive 236ca5d)", "superseded",
     "the same before issue 49's memory cuts"),
    ("slab_calibration.*", "python tools/slab_calibration.py", "current",
     "diffusion model fitted to the CDT calibration captures (docs/validation/"
     "slab-calibration.md)"),
    ("hidden_face_kernel.json", "python tools/hidden_face_kernel.py", "current",
     "CDT's kernel against Eq. 8's midpoint placement (docs/validation/hidden-face-kernel.md)"),
    ("lct_release_check.*", "python tools/lct_release_check.py --methods lct iterative", "current",
     "the LCT release read as released: defaults against the published pipeline "
     "(docs/validation/lct-release.md)"),
    ("lct_release_check_lct.*", "python tools/lct_release_check.py --brdf default lambertian "
     "--out tools/results/lct_release_check_lct", "current",
     "the same for LCT alone, with the reader's default and Lambertian reflectance "
     "(docs/validation/lct-release.md)"),
    ("lct_detail_study.*", "python tools/lct_detail_study.py", "current",
     "the diffuse S's fine detail: the published pipeline's split halves, clnlos's LCT "
     "stages morphed into the published ones, a point's registration "
     "(docs/validation/lct-release.md)"),
    ("experiments/lct_release_iterative/lct_release_iterative.*",
     "python tools/lct_release_check.py --methods iterative --brdf default auto --out "
     "tools/results/experiments/lct_release_iterative/lct_release_iterative", "current",
     "the iterative method on the LCT release, defaults and brdf auto, after issue 47's "
     "SNR-matched stop and falloff hint (docs/validation/lct-release.md; its iterative rows "
     "supersede lct_release_check.*'s)"),
    ("experiments/power_iterations/power_iterations.*", "python tools/power_iteration_check.py",
     "current", "the step size's power iteration after 4-15 iterations against 60, per grid and "
     "lobe the iterative method builds (docs/performance.md)"),
    ("experiments/search_grid/search_grid.*", "python tools/search_grid_check.py", "current",
     "the reproducibility search on block sums against the search on the capture's grid, "
     "random 128^3 captures behind the slab (docs/validation/parameter-rules.md)"),
    ("measured_rule_check.*", "python tools/measured_rule_check.py --methods lct fk",
     "current", "the rule a measured capture gets (GCV, the model's accuracy combined) on "
     "the oracle's captures, beside the default and the oracle (docs/validation/"
     "parameter-rules.md)"),
    ("experiments/brdf_iteration/bench.*", "clnlos bench --only brdf_iteration -o "
     "tools/results/experiments/brdf_iteration", "current",
     "per lobe the iterative method's iteration and solve against the Lambertian one and "
     "the FFT pair, the error each separable term buys (docs/brdf.md)"),
    ("retro_identifiability.*", "python tools/retro_identifiability.py", "current",
     "held-out scores of each reflectance model on the LCT release (docs/brdf.md)"),
    ("lct_rig.json", "python tools/study_rig.py examples/studies/lct_rig.toml", "current",
     "the LCT rig's study file: the exposure a white and a retroreflective S need, the five "
     "released captures beside their twins (docs/real-materials.md)"),
    ("cdt_rig.json", "python tools/study_rig.py examples/studies/cdt_rig.toml", "current",
     "the CDT rig's study file: the exposure a white S needs behind the slab, the three "
     "released captures beside their twins (docs/real-materials.md)"),
    ("real_materials.*", "python tools/real_materials.py --quick", "current",
     "photons a real target needs per inversion x reflectance, the twins, the charts "
     "(docs/real-materials.md)"),
    ("real_cdt_defaults.*", "python tools/real_cdt_defaults.py", "current",
     "real captures: defaults against the published settings (docs/validation/"
     "real-captures.md)"),
    ("mitransient_check.*", "python tools/mitransient_check.py", "current",
     "bistatic transport against Mitsuba 3 + mitransient (docs/validation/transport.md)"),
    ("study_transport.*", "python tools/study_transport.py", "current",
     "the material table under both transports (docs/validation/transport.md)"),
    ("study_transport_3x6.*", "python tools/study_transport.py --rings 3 --angles 6 "
     "--stem study_transport_3x6 --materials ...", "current",
     "the closest materials at 3 x 6 face samples"),
    ("study_transport_faces.*", "python tools/study_transport_faces.py", "current",
     "convergence of the bistatic face samples (clnlos/study/findings/transport.py)"),
    ("confocal_error.*", "python tools/confocal_error.py", "current",
     "Eq. 9 against Eq. 8 per preset (clnlos/study/findings/confocal_error.py)"),
    ("confocal_error_16pt.*", "python tools/confocal_error.py --points 16", "current",
     "the same on a 16-point scan"),
    ("legibility_classifier.json", "clnlos study --quick --real-data ../shared/data (at "
     "bf147bd, the 32 x 32 quick grid; the label, calibration and augmentation variants "
     "measured by hand)", "superseded",
     "the legibility classifier's splits, real-capture thinning, cost and the variants not "
     "taken (issue 40); the current numbers are in the study's results.json"),
    ("legibility_thinning_real.png", "clnlos study --quick --real-data ../shared/data (at "
     "bf147bd)", "superseded", "the thinned real captures' MIPs with P(legible) (issue 40)"),
    ("train_judge.json", "python tools/train_judge.py --real-data ../shared/data --compare "
     "JUDGE (JUDGE: the judge.json of clnlos study --quick --real-data ../shared/data at "
     "b75462e)", "current",
     "the shipped legibility judge's training set, held-out splits, real ladders, leave-one-"
     "capture-out, mock releases, and the judge before it on the same (docs/validation/"
     "legibility-judge.md; the judge itself: clnlos/data/legibility_judge.json)"),
    ("legibility_real_ladders.png", "python tools/train_judge.py --real-data ../shared/data",
     "current", "every real capture's thinning ladder: its reconstructions and P(legible) as "
     "a capture and as the default LCT volume (docs/validation/legibility-judge.md)"),
    ("legibility_twins.png", "python tools/train_judge.py --real-data ../shared/data",
     "current", "twins of every kind down their ladders, labelled"),
    ("brdf_operator_check.*", "python tools/brdf_operator_check.py", "current",
     "the BRDF-aware inversion's operator against simulate (docs/brdf.md)"),
    ("brdf_evaluate.*", "clnlos brdf evaluate ../shared/data/brdf -o tools/results/"
     "brdf_evaluate.csv --splits 2", "current",
     "interpolation and extrapolation scores of the BRDF models (the CLI's row format: no "
     "provenance field)"),
    ("experiments/oracle/oracle_params.*", "python tools/oracle_params.py", "current",
     "auto parameters against the oracle grid, seed 0 (docs/validation/parameter-rules.md)"),
    ("experiments/oracle/exposure_sweep*", "python tools/oracle_params.py", "current",
     "the exposure sweep and its summary"),
    ("experiments/oracle/oracle_seeds.*", "python tools/oracle_params.py --seeds 0 1 2",
     "current", "the oracle table over noise seeds"),
    ("experiments/oracle/oracle_seeds_summary.*", "python tools/oracle_params.py --seeds 0 1 2",
     "current", "its mean and spread"),
    ("experiments/oracle/oracle_seeds_before*", "python tools/oracle_params.py --seeds 0 1 2 "
     "(before the UPRE light-cone rule)", "superseded",
     "the rules before issue 24's UPRE and noise L1 weight, kept for comparison"),
    ("experiments/oracle/oracle_holdout*", "python tools/oracle_params.py --holdout --seeds 1 2",
     "current", "the 16 held-out captures"),
    ("experiments/oracle/oracle_grids*", "python tools/oracle_params.py --grids --seeds 0 1 2 "
     "[--holdout]", "current", "every grid setting's IoU and the oracle transfer test"),
    ("experiments/oracle/oracle_random_20261203*", "python tools/oracle_params.py --random "
     "20261203 --seeds 1 2", "current",
     "one of the two draws the reproducibility bars were chosen on"),
    ("experiments/oracle/oracle_random_20261204*", "python tools/oracle_params.py --random "
     "20261204 --seeds 1 2", "current", "the check draw of LCT's and f-k's constants"),
    ("experiments/oracle/oracle_random_20261205*", "python tools/oracle_params.py --random "
     "20261205 --seeds 1 2", "current", "a second check draw (f-k's 1e8 decade)"),
    ("experiments/oracle/oracle_random_20261206*", "python tools/oracle_params.py --random "
     "20261206 --seeds 1 2", "current", "drawn after every constant was fixed"),
    ("experiments/snr_rule_thinning/snr_rule_thinning.*", "python tools/snr_rule_check.py",
     "current", "the thinning rule on captures it had not seen"),
    ("experiments/snr_rule_thinning/snr_rule_thinning_both_ways.*",
     "python tools/snr_rule_check.py --both-ways", "current",
     "the search in both directions (why only deeper)"),
    ("experiments/snr_rule_thinning/snr_rule_thinning_table.*",
     "python tools/snr_rule_check.py --table-seeds 0 1 2 --holdout-seeds --fresh-seeds "
     "--out snr_rule_thinning_table", "current",
     "the rule on the oracle table at three seeds"),
    ("experiments/snr_rule_thinning/snr_rule_thinning_sweep.*",
     "python tools/snr_rule_check.py --sweep-seeds 0 1 2 --holdout-seeds 1 --fresh-seeds "
     "--out snr_rule_thinning_sweep", "current",
     "the rule on the exposure sweep"),
    ("experiments/solver/solver_iterations.*", "python tools/solver_check.py", "current",
     "the working-set solver against plain FISTA (docs/performance.md)"),
    ("experiments/lct_low_exposure/*", "(a diagnosis script of issue 24, not kept)",
     "superseded", "the LCT low-exposure diagnosis: criteria measured and rejected "
     "(docs/validation/parameter-rules.md); no command re-creates it"),
)


def entry_of(rel: str) -> tuple[str, str, str, str] | None:
    """The last entry whose glob matches ``rel`` (later entries are more specific)."""
    found = None
    for e in ENTRIES:
        if fnmatch.fnmatch(rel, e[0]):
            found = e
    return found


def result_files() -> list[str]:
    return sorted(str(p.relative_to(RESULTS)) for p in RESULTS.rglob("*")
                  if p.is_file() and p != INDEX)


def last_commit(rel: str) -> str:
    """Short hash and date of the last commit that changed the file's content (renames
    followed); "uncommitted" for a file git does not know yet."""
    out = subprocess.run(["git", "log", "--follow", "--diff-filter=AM", "-1",
                          "--format=%h %ad", "--date=short", "--", f"tools/results/{rel}"],
                         capture_output=True, text=True, cwd=ROOT).stdout.strip()
    return out or "uncommitted"


def render() -> str:
    lines = ["# tools/results: index",
             "",
             "Every committed result file: the command that produces it (from the repository "
             "root; `tools/results_index.py` regenerates this page), the commit that last "
             "changed its content, and whether it is current (what the code does today) or "
             "superseded (kept as the record of a decision). Result JSON written since 0.2.0 "
             "records the clnlos version and commit itself (`clnlos_version`, "
             "`provenance.clnlos_git_commit`). Tuning logs are under `experiments/<topic>/`.",
             "",
             "| file | command | commit | status | what |",
             "|---|---|---|---|---|"]
    for rel in result_files():
        e = entry_of(rel)
        if e is None:
            raise SystemExit(f"{rel}: no entry in tools/results_index.py ENTRIES")
        lines.append(f"| `{rel}` | `{e[1]}` | {last_commit(rel)} | {e[2]} | {e[3]} |")
    return "\n".join(lines) + "\n"


def main() -> int:
    INDEX.write_text(render(), encoding="utf-8")
    print(f"wrote {INDEX}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
