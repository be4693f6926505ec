"""The bank's step (the bridge's path) answers what the scalar ``tracker_step`` does, row by
row, on random canals and random walks (hypothesis).

Walks mix every kind of pose a live stream sends: following its targets, anywhere inside,
outside, far away (50 m, 1e308 that overflows the plane distances), jumps backward, jumps
ahead past the window, beyond either end, restarts, and the same pose again (so that suspect
poses run into sustained ones and are followed). Each step moves a random subset of
the streams, so the bank sees single rows (the scalar step) and batches (the vectorised
pass) of varying sizes in any slot order.
"""

from __future__ import annotations

import numpy as np
from core_data import bent_copy, sine_curve
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import canal_core
from canal_core.tracker import TrackerTarget
from canal_core.tracker_bank import TrackerBank
from canal_core.tracker_batch import TrackerBatch, tracker_steps
from canal_core.tracker_kernel import compile_step_rows, step_rows

KINDS = ["follow", "follow", "follow", "inside", "outside", "far", "far", "back", "ahead",
         "ahead", "end", "start", "restart", "again", "again", "again"]


@st.composite
def canals(draw: st.DrawFn) -> canal_core.Canal:
    """A fitted circle-section canal on a random smooth curve, 2-D or 3-D, with or without
    section times and (3-D) orientations."""
    dim = draw(st.sampled_from([2, 3, 3]))
    return random_canal(draw(st.integers(0, 2**31 - 1)), dim,
                        draw(st.sampled_from([3, 4, 12, 40, 90, 90])), draw(st.booleans()),
                        dim == 3 and draw(st.booleans()))


def random_canal(seed: int, dim: int, n_samples: int, timed: bool,
                 oriented: bool) -> canal_core.Canal:
    """The canal :func:`canals` draws."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    s, base = sine_curve(rng, dim, 60, 2.5, 1.0, 2.0)
    demos, times, quats = [], [], []
    for _ in range(int(rng.integers(3, 6))):
        u, demo = bent_copy(rng, s, base)
        demos.append(demo)
        times.append(np.cumsum(rng.uniform(0.005, 0.02, len(u))))
        angles = np.outer(u, rng.uniform(-90.0, 90.0, 3)) + rng.normal(0.0, 2.0, 3)
        quats.append(Rotation.from_euler("xyz", angles, degrees=True).as_quat())
    return canal_core.fit(demos, n_samples=n_samples, timestamps=times if timed else None,
                          orientations=quats if oriented else None)


def _pose(canal: canal_core.Canal, kind: str, x: np.ndarray, target: np.ndarray,
          at: int, rng: np.random.Generator) -> np.ndarray:
    """The next live position of a stream at section ``at`` (a kind of :data:`KINDS`)."""
    n, dim = canal.directrix.shape
    r = float(canal.radii.max())
    if kind == "follow":
        return x + 0.4 * (target - x) + 0.05 * r * rng.standard_normal(dim)
    if kind == "again":
        return x.copy()
    if kind == "far":
        far = [np.full(dim, 50.0), np.full(dim, 1e308), np.full(dim, -1e308),
               np.eye(dim)[int(rng.integers(dim))] * 1e308]
        return far[int(rng.integers(len(far)))]
    tangent0, tangent1 = canal.tangents[0], canal.tangents[-1]
    spacing = float(np.linalg.norm(np.diff(canal.directrix, axis=0), axis=1).mean())
    if kind == "end":
        return canal.directrix[-1] + rng.uniform(-0.5, 3.0) * spacing * tangent1
    if kind == "start":
        return canal.directrix[0] - rng.uniform(-0.5, 3.0) * spacing * tangent0
    section = {"back": int(rng.integers(0, max(at, 1))),
               "ahead": int(rng.integers(min(at + 18, n - 2), n - 1)),
               }.get(kind, int(rng.integers(0, n - 1)))
    # off the section planes (a point exactly on a plane is a tie rounding may break
    # either way) and in a random in-plane direction, inside or outside the boundary
    eta = rng.uniform(0.0, 0.95) if kind in ("inside", "back", "ahead") else rng.uniform(1.1, 5.0)
    along = rng.uniform(0.1, 0.9) * (canal.directrix[section + 1] - canal.directrix[section])
    direction = rng.standard_normal(dim - 1)
    direction /= np.linalg.norm(direction)
    offset = eta * float(canal.radii[section]) * (direction @ canal.basis[section])
    return canal.directrix[section] + along + offset


def _same(got: TrackerTarget, e: TrackerTarget) -> None:
    """``got`` equals the scalar answer ``e`` (floats up to a reordered sum's last bits)."""
    assert (got.section_index, got.inside, got.done) == (e.section_index, e.inside, e.done)
    np.testing.assert_allclose(got.target, e.target, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(got.progress, e.progress, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(got.eta, e.eta, rtol=1e-9, atol=1e-12)
    assert (got.velocity is None) == (e.velocity is None)
    if got.velocity is not None and e.velocity is not None:
        np.testing.assert_allclose(got.velocity, e.velocity, rtol=1e-9, atol=1e-9)
    assert (got.orientation is None) == (e.orientation is None)
    if got.orientation is not None and e.orientation is not None:
        np.testing.assert_array_equal(got.orientation, e.orientation)


def _row(batch: TrackerBatch, j: int) -> TrackerTarget:
    """Row ``j`` of a bank's answers as a :class:`TrackerTarget`."""
    return TrackerTarget(
        batch.target[j], float(batch.progress[j]), float(batch.eta[j]),
        int(batch.section_index[j]), bool(batch.inside[j]), bool(batch.done[j]),
        None if batch.velocity is None else batch.velocity[j],
        None if batch.orientation is None else batch.orientation[j])


def _packed_row(bank: TrackerBank, rows: np.ndarray, j: int) -> TrackerTarget:
    """Row ``j`` of :meth:`TrackerBank.step_packed` read by its documented layout."""
    d = bank.geometry.centres.shape[1]
    row = rows[j]
    assert row.shape == (2 * d + 9,)
    velocity, orientation = row[d + 5:2 * d + 5], row[2 * d + 5:]
    assert bank.has_velocity or np.isnan(velocity).all()
    assert bank.has_orientation or np.isnan(orientation).all()
    assert row[d + 3] in (0.0, 1.0) and row[d + 4] in (0.0, 1.0)
    assert row[d + 2] == int(row[d + 2])
    return TrackerTarget(
        row[:d], float(row[d]), float(row[d + 1]), int(row[d + 2]), bool(row[d + 3]),
        bool(row[d + 4]), velocity if bank.has_velocity else None,
        orientation if bank.has_orientation else None)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(canal=canals(), seed=st.integers(0, 2**31 - 1),
       n_streams=st.sampled_from([1, 2, 3, 6, 17]), lookahead=st.integers(1, 4))
def test_bank_step_equals_the_scalar_step_on_random_canals_and_walks(
        canal: canal_core.Canal, seed: int, n_streams: int, lookahead: int) -> None:
    """The numpy pass (what a bank steps with while the kernel compiles)."""
    walk_and_compare(canal, seed, n_streams, lookahead, compiled=False)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(canal=canals(), seed=st.integers(0, 2**31 - 1),
       n_streams=st.sampled_from([1, 2, 3, 6, 17]), lookahead=st.integers(1, 4))
def test_compiled_bank_step_equals_the_scalar_step_on_random_canals_and_walks(
        canal: canal_core.Canal, seed: int, n_streams: int, lookahead: int) -> None:
    """The compiled kernel (what a live bridge steps with)."""
    assert compile_step_rows() is not None, "numba is a dependency of the dev install"
    walk_and_compare(canal, seed, n_streams, lookahead, compiled=True)


def test_the_kernel_source_runs_as_plain_python_and_agrees() -> None:
    """numba compiles the Python function as written: run uncompiled (the same source) on a
    bank's arrays it gives what the compiled kernel gives, so a reader can step through it."""
    canal = random_canal(7, 3, 40, True, True)
    rng = np.random.default_rng(3)
    banks = [TrackerBank(canal.tracker(lookahead=2).geometry, lookahead=2) for _ in range(2)]
    slots = [[bank.add() for _ in range(4)] for bank in banks]
    kernel = compile_step_rows()
    assert kernel is not None
    for k in range(30):
        p = canal.directrix[(k + np.arange(4)) % canal.n_sections] + 0.02 * rng.standard_normal(
            (4, 3))
        got = []
        for bank, sl, fn in zip(banks, slots, (kernel, step_rows), strict=True):
            got.append(bank._compiled_rows(fn, np.array(sl), p))
        np.testing.assert_allclose(got[0], got[1], rtol=1e-12, atol=1e-15)
        np.testing.assert_array_equal(got[0][:, 5], got[1][:, 5])  # the section index
    np.testing.assert_array_equal(banks[0].index, banks[1].index)


def walk_and_compare(canal: canal_core.Canal, seed: int, n_streams: int,
                     lookahead: int, compiled: bool) -> None:
    """Walk ``n_streams`` streams through the bank, tracker_steps and scalar trackers."""
    rng = np.random.default_rng(seed)
    scalar = [canal.tracker(lookahead=lookahead) for _ in range(n_streams)]
    bank = TrackerBank(scalar[0].geometry, lookahead=lookahead, capacity=2, compiled=compiled)
    slots = [bank.add() for _ in range(n_streams)]
    n = canal.n_sections
    x = canal.directrix[rng.integers(0, n, n_streams)] + 0.3 * float(canal.radii.min()) * (
        rng.standard_normal((n_streams, canal.directrix.shape[1])))
    last: list[TrackerTarget | None] = [None] * n_streams
    for step in range(40):
        rows = rng.permutation(n_streams)[: int(rng.integers(1, n_streams + 1))]
        for r in rows.tolist():
            kind = KINDS[int(rng.integers(len(KINDS)))]
            if kind == "restart":
                start = int(rng.integers(0, n))
                scalar[r].reset(start)
                bank.reset(slots[r], start)
                kind = "inside"
            previous = last[r]
            target = x[r] if previous is None else previous.target
            x[r] = _pose(canal, kind, x[r], target, scalar[r].index, rng)
        before = [scalar[r].state for r in rows.tolist()]
        with np.errstate(over="ignore", invalid="ignore"):  # the far poses overflow
            expected = [scalar[r].step(x[r]) for r in rows.tolist()]
        # alternately the answers as arrays and packed in rows (the live bridge's)
        if step % 2:
            packed = bank.step_packed([slots[r] for r in rows.tolist()], x[rows])
            answers = [_packed_row(bank, packed, j) for j in range(len(rows))]
        else:
            batch = bank.step([slots[r] for r in rows.tolist()], x[rows])
            answers = [_row(batch, j) for j in range(len(rows))]
        # the same rows through tracker_steps (states as objects)
        with np.errstate(over="ignore", invalid="ignore"):  # one row: the scalar step
            again, states = tracker_steps(scalar[0].geometry, before, x[rows], lookahead)
        for j, (r, e) in enumerate(zip(rows.tolist(), expected, strict=True)):
            _same(answers[j], e)
            _same(again[j], e)
            for state in (bank.state(slots[r]), states[j]):
                assert state.index == scalar[r].state.index
                assert state.strikes == scalar[r].state.strikes
                assert (state.pending is None) == (scalar[r].state.pending is None)
                if state.pending is not None:
                    np.testing.assert_array_equal(state.pending, scalar[r].state.pending)
                assert (state.eta is None) == (scalar[r].state.eta is None)
                np.testing.assert_allclose(
                    np.nan if state.eta is None else state.eta,
                    np.nan if scalar[r].state.eta is None else scalar[r].state.eta,
                    rtol=1e-9, atol=1e-12)
            last[r] = e
