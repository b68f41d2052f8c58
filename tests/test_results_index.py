"""tools/results has an index and no orphans: INDEX.md lists exactly the files there, each with
an existing producer (a tools/ script or a clnlos command) and a status; the writers of result
JSON record the version and commit."""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

from clnlos.bench.harness import read_rows, write_rows

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "tools" / "results"
ROW = re.compile(r"^\| `([^`]+)` \| `([^`]+)` \| ([^|]+) \| (current|superseded) \|")


def index_rows() -> dict[str, tuple[str, str, str]]:
    text = (RESULTS / "INDEX.md").read_text(encoding="utf-8")
    return {m.group(1): m.group(2, 3, 4) for m in map(ROW.match, text.splitlines()) if m}


def test_index_lists_exactly_the_result_files():
    sys.path.insert(0, str(ROOT / "tools"))
    try:
        import results_index
    finally:
        sys.path.pop(0)
    on_disk = set(results_index.result_files())
    listed = set(index_rows())
    assert listed == on_disk, (sorted(on_disk - listed), sorted(listed - on_disk))
    assert all(results_index.entry_of(f) is not None for f in on_disk)


def test_every_producer_exists():
    for name, (command, commit, status) in index_rows().items():
        script = re.search(r"tools/(\w+)\.py", command)
        if script:
            assert (ROOT / "tools" / f"{script.group(1)}.py").is_file(), (name, command)
        elif command.startswith("clnlos "):
            assert command.split()[1] in ("bench", "brdf", "study"), (name, command)
        else:
            assert status == "superseded", (name, command)  # nothing re-creates it
        assert re.match(r"[0-9a-f]{7,} \d{4}-\d\d-\d\d|uncommitted", commit.strip()), name


def test_result_json_records_version_and_commit(tmp_path):
    rows = [{"case": "a", "iou": 0.5}]
    _, json_path = write_rows(rows, tmp_path, "r")
    doc = json.loads(json_path.read_text())
    assert doc["clnlos_version"] and doc["provenance"]["clnlos_version"] == doc[
        "clnlos_version"]
    assert "clnlos_git_commit" in doc["provenance"] or not (ROOT / ".git").exists()
    assert read_rows(json_path) == rows
    legacy = tmp_path / "old.json"  # a file from before the provenance: rows only
    legacy.write_text(json.dumps(rows))
    assert read_rows(legacy) == rows
