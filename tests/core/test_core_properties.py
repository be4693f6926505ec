"""Property tests (hypothesis): containment by construction, reproduction stays inside, eta kept.

Tolerance: reproduced points lie exactly on their cross-sections (eta <= 1 up to 1e-9
relative). Demo samples between two sections are judged against the linear blend of the two
and may exceed it by the chord error; that is measured in test_core_lasa.py, not here.
"""

from __future__ import annotations

import numpy as np
from core_data import bent_copy, sine_curve
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_core_sections import assert_points_inside

import canal_core

KINDS = st.sampled_from(["circle", "mec", "ellipse", "spline"])


@st.composite
def demo_sets(draw: st.DrawFn) -> list[np.ndarray]:
    seed = draw(st.integers(0, 2**31 - 1))
    n_demos = draw(st.integers(3, 7))
    dim = draw(st.sampled_from([2, 3]))
    rng = np.random.default_rng(seed)
    # A random smooth base curve (sum of a few sines) plus smooth random deviations.
    s, base = sine_curve(rng, dim, 60, 1.5, 1.0, 2.0)
    return [bent_copy(rng, s, base)[1] for _ in range(n_demos)]


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(demos=demo_sets(), kind=KINDS, data=st.data())
def test_random_canals_contain_demos_and_reproductions(demos, kind, data) -> None:
    canal = canal_core.fit(demos, cross_section=kind, n_samples=60)
    assert_points_inside(canal)
    # A random interior start: a point at ratio < 1 on a random section and direction.
    i = data.draw(st.integers(0, canal.n_sections - 2))
    eta = data.draw(st.floats(0.0, 0.95))
    angle = data.draw(st.floats(0.0, 2 * np.pi))
    direction = np.array([np.cos(angle), np.sin(angle)])[: canal.dim - 1]
    if canal.dim == 2:
        direction = np.array([1.0 if angle < np.pi else -1.0])
    reach = canal_core.cross_sections.boundary_distance(canal.sections, np.array([i]), direction[None])[0]
    start = canal.directrix[i] + eta * reach * np.einsum("k,kd->d", direction, canal.basis[i])
    result = canal.reproduce_detailed(start)
    assert np.isfinite(result.positions).all()
    assert not result.projected
    assert result.eta <= 1.0
    loc = canal.locate(result.positions[1:])
    assert (loc.eta <= 1.0 + 1e-9).all()
