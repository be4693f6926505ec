"""bench/quality.py prepares every demo the same way for every method and scores the same folds."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from bench import quality  # noqa: E402


def test_still_ends_are_trimmed_and_every_demo_becomes_200_points_evenly_in_its_time() -> None:
    t = np.arange(0.0, 3.0, 0.01)
    moving = np.clip((t - 1.0) / 1.0, 0.0, 1.0)  # still for 1 s, moves 1 m in 1 s, still for 1 s
    pos = np.column_stack([moving, np.zeros_like(t), np.zeros_like(t)])
    arrays = quality.demo_arrays(t, pos)
    assert arrays.shape == (quality.N, 3)
    assert arrays[0, 0] < 0.011 and arrays[-1, 0] > 0.989
    steps = np.diff(arrays[:, 0])
    np.testing.assert_allclose(steps, steps.mean(), rtol=0.05)  # evenly in time = evenly here


def test_start_regions_split_starts_farther_apart_than_the_threshold() -> None:
    starts = np.array([[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.5, 0.0, 0.0], [0.51, 0.01, 0.0]])
    labels = quality.start_regions(starts)
    assert labels[0] == labels[1] != labels[2] == labels[3]


def test_every_method_is_scored_on_the_same_folds_and_the_canal_reports_containment() -> None:
    sets = {"reach": [quality.Demo(quality.demo_arrays(t, p), person=str(k % 2 + 1))
                      for k, (t, p) in enumerate(quality.raw_logs(3, quality.base_paths()["reach"], n_demos=4))]}
    methods = {quality.DEFAULT: quality.CANALS[quality.DEFAULT], "DMP": quality.PEERS["DMP"]}
    records = quality.evaluate("raw 3-D", sets, methods)
    assert len(records) == 8 and not any("error" in r for r in records)
    canal = [r for r in records if r["method"] == quality.DEFAULT]
    assert all(r["train in"] == 1.0 for r in canal)
    assert all(0.0 < r["dtw"] < 0.1 for r in records)  # the path is about 1 long
    table = quality.ratio_table(records, ["raw 3-D"], list(methods))
    assert "DMP" in table and "held-out starts inside" in table
    dmp = {r["fold"]: r["dtw"] for r in records if r["method"] == "DMP"}
    closer = sum(r["dtw"] < dmp[r["fold"]] for r in canal)
    assert f"| folds the defaults follow closer than the best peer | {closer}/4 |" in table
