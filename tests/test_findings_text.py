"""The findings' wording where a number is a limit of what was tried or the intervals overlap
(clnlos.study.findings.text; issue 51 item 5)."""

import pytest

from clnlos.study.findings.text import (
    any_separated,
    dominance_verdict,
    intervals_overlap,
    limit_text,
    verdict_text,
)
from clnlos.study.score.legibility import wilson_interval

EXPOSURES = (0.001, 0.01, 0.1, 1.0)


def test_a_threshold_at_the_smallest_value_tried_is_a_limit():
    assert limit_text(0.001, EXPOSURES, "s") == "<= 0.001 s (the smallest tried)"
    assert limit_text(0.1, (0.3, 0.2, 0.1), "m") == "<= 0.1 m (the smallest tried)"
    assert limit_text(0.01, EXPOSURES, "s") == "0.01 s"
    assert limit_text(1.0, EXPOSURES, "s") == "1 s"  # reached at the largest: a threshold
    assert limit_text(None, EXPOSURES, "s") == "> 1 s (not reached: the largest tried)"
    with pytest.raises(ValueError):
        limit_text(0.1, (), "s")


def test_intervals_overlap():
    assert intervals_overlap([0.1, 0.5], [0.4, 0.9])
    assert intervals_overlap([0.1, 0.5], [0.5, 0.9])  # a shared end point
    assert not intervals_overlap([0.1, 0.3], [0.4, 0.9])
    assert not intervals_overlap([0.6, 0.9], [0.1, 0.5])
    assert any_separated([[0.0, 0.2], [0.1, 0.5], [0.6, 1.0]])
    assert not any_separated([[0.0, 0.7], [0.3, 0.9]])
    assert not any_separated([[0.0, 0.2]])


def _row(material, value, k, n):
    return {"material": material, "value": value,
            "identification": {"accuracy": k / n, "ci": wilson_interval(k, n)}}


def test_no_verdict_on_two_glyphs_per_point():
    """2 glyphs a point (Wilson 0.09-0.91 at 1 of 2): all 0/2 to 2/2 intervals overlap."""
    rows = [_row("a", 0.1, 1, 2), _row("a", 0.3, 2, 2), _row("b", 0.1, 0, 2),
            _row("b", 0.3, 1, 2)]
    assert dominance_verdict(rows, geometry_effect=0.5, material_effect=0.25) is None
    assert verdict_text(None) == "no verdict: the Wilson intervals overlap"


def test_a_verdict_where_the_intervals_separate():
    # 20 glyphs a point: letter size moves each material from 2/20 to 19/20 (separate),
    # the two materials agree at each size (overlap): geometry dominates
    rows = [_row("a", 0.1, 2, 20), _row("a", 0.3, 19, 20),
            _row("b", 0.1, 3, 20), _row("b", 0.3, 18, 20)]
    assert dominance_verdict(rows, geometry_effect=0.85, material_effect=0.05) == "geometry"
    assert verdict_text("geometry") == "geometry dominates"
    # materials apart at each value, each flat over it: material dominates
    rows = [_row("a", 0.1, 19, 20), _row("a", 0.3, 20, 20),
            _row("b", 0.1, 1, 20), _row("b", 0.3, 2, 20)]
    assert dominance_verdict(rows, geometry_effect=0.05, material_effect=0.9) == "material"
