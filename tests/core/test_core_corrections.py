"""Corrections: include grows the canal locally to hold a path, exclude narrows it on one side."""

from __future__ import annotations

import json
import re
import tracemalloc

import numpy as np
import pytest
from core_data import helix_demos, sleeve_demos
from raw_logs import ur5e_demos

import canal_core
from canal_core import InvalidInputError
from canal_core.corrections import (
    MIN_WIDTH_FRACTION,
    blend_dropped_crossings,
    correction_glitches,
    longest_blend,
    path_crossings,
    reapplied_canal,
)
from canal_core.cross_sections import boundary_distance

KINDS = ("circle", "mec", "ellipse", "spline")
ARRAYS = ("directrix", "tangents", "normals", "binormals", "arclength", "section_points")


@pytest.fixture(scope="module")
def demos() -> list[np.ndarray]:
    return helix_demos(0.05, 6)


@pytest.fixture(scope="module")
def canal(demos: list[np.ndarray]) -> canal_core.Canal:
    return canal_core.fit(demos, n_samples=200, timing="arc")  # plane numbers below are on arc length


def include_path(canal: canal_core.Canal, first: int = 80, last: int = 110, bulge: float = 0.12) -> np.ndarray:
    idx = np.arange(first, last + 1)
    off = 0.02 + bulge * np.sin(np.linspace(0.0, np.pi, idx.size))[:, None]
    return np.asarray(canal.directrix[idx] + off * canal.normals[idx])


def pushed_run(canal: canal_core.Canal, start_section: int = 60, depth: float = 0.6) -> tuple[np.ndarray, np.ndarray]:
    """The canal's reproduction from a start near the +normal wall, and the same run pushed
    towards -normal by ``depth`` of that wall's distance around its 40th sample (a person
    keeping the arm off that side)."""
    i = start_section
    wall = float(boundary_distance(canal.sections, np.array([i]), np.array([[1.0, 0.0]]))[0])
    start = canal.directrix[i] + 0.8 * wall * canal.normals[i]
    run = canal.reproduce(start)
    k = np.arange(run.shape[0])
    sec = np.clip(start_section + k, 0, canal.n_sections - 1)
    walls = boundary_distance(canal.sections, sec, np.tile([1.0, 0.0], (k.size, 1)))
    bump = np.exp(-0.5 * ((k - 40) / 8.0) ** 2)
    return run, run - (depth * walls * bump)[:, None] * canal.normals[sec]


def unchanged_outside(parent: canal_core.Canal, child: canal_core.Canal, lo: int, hi: int) -> None:
    outside = np.ones(parent.n_sections, dtype=bool)
    outside[lo : hi + 1] = False
    for name in ARRAYS:
        a, b = getattr(parent, name), getattr(child, name)
        if a is None:  # binormals of a planar canal
            assert b is None
            continue
        assert np.array_equal(a[outside], b[outside]), name
    for name, values in parent.sections.params.items():
        assert np.array_equal(values[outside], child.sections.params[name][outside]), name


def cut_sides(canal: canal_core.Canal, path: np.ndarray) -> np.ndarray:
    """How far a path goes past each exclude cut (> 0: on the excluded side), per cut section."""
    applied = canal.corrections[-1]
    assert applied.cut_points is not None and applied.cut_directions is not None
    crossed, coords = path_crossings(path, canal.directrix, canal.tangents, canal.basis, 3.0 * canal.radii)
    idx = np.arange(applied.first, applied.last + 1)
    ok = ~np.isnan(applied.cut_points[:, 0]) & crossed[idx]
    world = canal.directrix[idx] + np.einsum("sk,skd->sd", coords[idx], canal.basis[idx])
    return np.asarray(np.einsum("sd,sd->s", world - applied.cut_points, applied.cut_directions)[ok])


def test_include_holds_the_path_and_changes_nothing_outside_its_span(
    canal: canal_core.Canal, demos: list[np.ndarray]
) -> None:
    path = include_path(canal)
    refined = canal.corrected("include", path, weight=1.0, label="wider here")
    applied = refined.corrections[0]
    # The path lies on planes 80 to 110; its ends cross a plane or two more where they tilt.
    assert 76 <= applied.first <= 80 and 110 <= applied.last <= 114
    assert applied.lo < applied.first and applied.hi > applied.last
    assert refined.contains(path).all()
    assert all(refined.contains(d).all() for d in demos)
    assert refined.radii[95] > canal.radii[95] * 1.5
    unchanged_outside(canal, refined, applied.lo, applied.hi)
    # Reproductions that start after the changed range are the parent's.
    for offset in (0.0, 0.02, 0.045):
        i = applied.hi + 3
        start = canal.directrix[i] + offset * canal.binormals[i] + 1e-4 * canal.tangents[i]
        np.testing.assert_allclose(refined.reproduce(start), canal.reproduce(start), atol=1e-9, rtol=0)


def test_include_weight_sets_how_far_the_directrix_moves(canal: canal_core.Canal) -> None:
    path = include_path(canal)
    moves = [
        np.linalg.norm(canal.corrected("include", path, weight=w).directrix[95] - canal.directrix[95])
        for w in (0.5, 1.0, 6.0)
    ]
    assert moves[0] < moves[1] < moves[2]
    # Weight w among n = 6 demos: the centre moves w / (n + w) of the way to the path.
    offset = np.linalg.norm(path[15] - canal.directrix[95])
    np.testing.assert_allclose(moves[2], 0.5 * offset, rtol=0.05)


def test_exclude_keeps_every_reproduction_on_the_side_the_person_showed(
    canal: canal_core.Canal, demos: list[np.ndarray]
) -> None:
    run, pushed = pushed_run(canal)
    refined = canal.corrected("exclude", pushed)
    applied = refined.corrections[0]
    assert applied.correction.kind == "exclude"
    # The unrefined run went past the cut; reproductions from anywhere before it no longer do.
    assert cut_sides(refined, run).max() > 0.01
    rng = np.random.default_rng(3)
    for _ in range(25):
        i = int(rng.integers(0, 60))
        angle, share = rng.uniform(0.0, 2.0 * np.pi), rng.uniform(0.0, 1.0)
        start = canal.directrix[i] + share * canal.radii[i] * (np.cos(angle) * canal.normals[i] + np.sin(angle) * canal.binormals[i])
        path = refined.reproduce(start)
        assert cut_sides(refined, path).max(initial=-1.0) <= 1e-9
    unchanged_outside(canal, refined, applied.lo, applied.hi)
    # Demonstrated samples that are now outside lie where the person excluded, and the model says so.
    for demo in demos:
        assert (refined.contains(demo) | refined.excluded(demo)).all()
    assert refined.exempt_crossings.any()
    assert not canal.exempt_crossings.any()


def test_tracker_targets_respect_an_exclusion(canal: canal_core.Canal) -> None:
    run, pushed = pushed_run(canal)
    refined = canal.corrected("exclude", pushed)
    tracker = refined.tracker()
    position = run[0].copy()
    targets = []
    for _ in range(run.shape[0] + 20):
        answer = tracker.step(position)
        targets.append(answer.target)
        position = answer.target
        if answer.done:
            break
    assert cut_sides(refined, np.array(targets)).max(initial=-1.0) <= 1e-6


def test_an_exclude_that_would_close_the_canal_is_refused(canal: canal_core.Canal) -> None:
    _, pushed = pushed_run(canal, depth=2.5)  # pushed across to beyond the far wall
    with pytest.raises(InvalidInputError) as err:
        canal.corrected("exclude", pushed)
    assert err.value.field == "kind"
    assert f"{MIN_WIDTH_FRACTION:.0%}" in err.value.message and "close" in err.value.message


@pytest.mark.parametrize(
    ("kind", "samples", "field"),
    [
        ("include", np.zeros((10, 2)), "samples"),  # wrong dimension
        ("include", "three", "samples"),
        ("sideways", None, "kind"),
    ],
)
def test_malformed_corrections_name_their_field(canal: canal_core.Canal, kind: str, samples: object, field: str) -> None:
    with pytest.raises(InvalidInputError) as err:
        canal.corrected(kind, include_path(canal) if samples is None else samples)
    assert err.value.field == field


def test_a_plan_at_fault_is_named_plan_and_an_include_takes_none(canal: canal_core.Canal) -> None:
    # The same pushed samples: a fine exclude with the directrix as plan; with a plan over
    # other sections, 5 m to the side or still, the plan is at fault (the samples were named).
    idx = np.arange(60, 90)
    pushed = canal.directrix[idx] + 0.5 * canal.radii[idx, None] * canal.normals[idx]
    assert canal.corrected("exclude", pushed, plan=canal.directrix[idx]).corrections[0].first >= 60
    for plan, said in ((canal.directrix[120:150], "over the sections the samples cross (60..89"),
                       (canal.directrix[idx] + [0.0, 5.0, 0.0], "a plan over the canal"),
                       (np.repeat(canal.directrix[70:71], 10, axis=0), "a plan that moves along")):
        with pytest.raises(InvalidInputError, match=re.escape(said)) as err:
            canal.corrected("exclude", pushed, plan=plan)
        assert err.value.field == "plan"
    with pytest.raises(InvalidInputError, match="expected no plan on an include correction") as err:
        canal.corrected("include", include_path(canal), plan=canal.directrix[80:111])
    assert err.value.field == "plan"


def test_short_far_and_weightless_corrections_are_refused(canal: canal_core.Canal) -> None:
    path = include_path(canal)
    with pytest.raises(InvalidInputError, match="at least 4") as err:
        canal.corrected("include", path[:3])
    assert err.value.field == "samples"
    with pytest.raises(InvalidInputError, match="outside every section") as err:
        canal.corrected("include", path + np.array([0.0, 0.0, 5.0]))
    assert err.value.field == "samples"
    # a robot held still on the canal was told its path was "outside every section"
    with pytest.raises(InvalidInputError, match=r"samples that move along the canal.*within 0 of "
                                                r"one point") as err:
        canal.corrected("include", np.repeat(canal.directrix[60:61], 30, axis=0))
    assert err.value.field == "samples"
    with pytest.raises(InvalidInputError) as err:
        canal.corrected("include", path, weight=0.0)
    assert err.value.field == "weight"
    with pytest.raises(InvalidInputError, match="pushed away") as err:
        canal.corrected("exclude", canal.reproduce(canal.directrix[60] + 0.01 * canal.normals[60]))
    assert err.value.field == "samples"


def test_a_refined_model_names_its_parent_and_round_trips(canal: canal_core.Canal) -> None:
    once = canal.corrected("include", include_path(canal), label="wider")
    twice = once.corrected("exclude", pushed_run(canal)[1])
    assert once.parent == canal.digest and twice.parent == once.digest
    data = json.loads(json.dumps(twice.to_dict()))
    back = canal_core.Canal.from_dict(data)
    assert [c.correction.kind for c in back.corrections] == ["include", "exclude"]
    assert back.corrections[0].correction.label == "wider"
    assert back.parent == twice.parent
    for name in ARRAYS:
        assert np.array_equal(getattr(back, name), getattr(twice, name))
    probe = canal.directrix[100:140] + 0.04 * canal.normals[100:140]
    assert np.array_equal(back.excluded(probe), twice.excluded(probe))
    # Re-applying the same corrections to the fit gives the same canal (a refit or an undo).
    again = reapplied_canal(canal, [c.correction for c in twice.corrections])
    assert np.array_equal(again.directrix, twice.directrix)
    assert np.array_equal(again.sections.params["radius"], twice.sections.params["radius"])


def test_models_written_before_corrections_still_load(canal: canal_core.Canal) -> None:
    data = canal.to_dict()
    del data["parent"], data["corrections"]
    back = canal_core.Canal.from_dict(data)
    assert back.parent is None and back.corrections == ()


@pytest.mark.parametrize("kind", KINDS)
def test_every_section_kind_is_corrected_locally(kind: str) -> None:
    demos = sleeve_demos(0.05, 6)
    canal = canal_core.fit(demos, cross_section=kind, n_samples=120)
    run, pushed = pushed_run(canal, start_section=30)
    refined = canal.corrected("exclude", pushed)
    applied = refined.corrections[0]
    unchanged_outside(canal, refined, applied.lo, applied.hi)
    assert cut_sides(refined, refined.reproduce(run[0])).max(initial=-1.0) <= 1e-9
    grown = canal.corrected("include", include_path(canal, 50, 70))
    assert grown.contains(include_path(canal, 50, 70)).all()
    for demo in demos:
        assert (refined.contains(demo) | refined.excluded(demo)).all()
        assert grown.contains(demo).all()


def test_a_path_that_folds_back_reads_the_same_crossings_either_way(canal: canal_core.Canal) -> None:
    # A hand shown over the canal wavers: it goes back over a few planes and on again. Read
    # from either end the same planes are crossed at the same points, and the first crossing
    # of a plane met three times is the one nearer the path's start as the path is read.
    idx = np.arange(len(canal.directrix))
    u = np.linspace(0.0, 1.0, 400)
    along = np.interp(0.2 + 0.6 * u + 0.05 * np.sin(6 * np.pi * u), np.linspace(0, 1, idx.size), idx)
    path = np.stack([np.interp(along, idx, canal.directrix[:, k]) for k in range(3)], axis=1)
    nearest = np.rint(along).astype(int)
    path = path + (0.3 * np.sin(9 * u) * canal.radii[nearest])[:, None] * canal.basis[nearest, 0]
    args = (canal.directrix, canal.tangents, canal.basis, 3.0 * canal.radii)
    crossed, coords = path_crossings(path, *args)
    crossed_back, coords_back = path_crossings(path[::-1].copy(), *args)
    assert crossed.sum() > 0.5 * idx.size
    np.testing.assert_array_equal(crossed_back, crossed)
    np.testing.assert_allclose(coords_back, coords, atol=1e-12, rtol=0)


def test_a_planar_canal_is_corrected_too() -> None:
    x = np.linspace(0.0, 1.0, 80)
    demos = [np.column_stack([x, 0.1 * np.sin(np.pi * x) + dy]) for dy in (-0.05, 0.0, 0.05)]
    canal = canal_core.fit(demos, n_samples=100)
    idx = np.arange(40, 61)
    wide = canal.directrix[idx] + 0.12 * canal.normals[idx]
    grown = canal.corrected("include", wide)
    assert grown.contains(wide).all()
    unchanged_outside(canal, grown, grown.corrections[0].lo, grown.corrections[0].hi)


def test_a_path_shown_against_the_canals_direction_corrects_it_as_shown_forwards(
    canal: canal_core.Canal,
) -> None:
    # A person who drags the arm back along the canal (end towards start) to say "here too"
    # used to be told the path was "outside every section": only forward plane crossings
    # counted. Where a path lies does not depend on which way it was shown.
    path = include_path(canal)
    forwards = canal.corrected("include", path)
    backwards = canal.corrected("include", path[::-1].copy())
    for name in ("directrix", "arclength", "section_points"):
        np.testing.assert_allclose(getattr(backwards, name), getattr(forwards, name), atol=1e-12, rtol=0)
    assert backwards.contains(path).all()
    # The correction keeps the samples as they were sent.
    np.testing.assert_array_equal(backwards.corrections[0].correction.samples, path[::-1])
    # A push shown backwards is the same push.
    run, pushed = pushed_run(canal)
    ahead = canal.corrected("exclude", pushed, plan=run)
    behind = canal.corrected("exclude", pushed[::-1].copy(), plan=run[::-1].copy())
    np.testing.assert_allclose(behind.directrix, ahead.directrix, atol=1e-12, rtol=0)
    assert behind.corrections[0].first == ahead.corrections[0].first


def line_canal() -> canal_core.Canal:
    """A straight 1 m canal of four demonstrations 5 cm around its axis (200 sections)."""
    x = np.linspace(0.0, 1.0, 60)
    demos = [np.column_stack([x, dy + 0.002 * np.sin(7 * x + i), dz + 0.002 * np.sin(7 * x + i + 1)])
             for i, (dy, dz) in enumerate([(0.05, 0.0), (-0.05, 0.0), (0.0, 0.05), (0.0, -0.05)])]
    return canal_core.fit(demos)


def test_a_glitch_sample_in_a_correction_path_is_dropped_as_a_demonstrations_would_be() -> None:
    # An include path 0.9 radii out over sections 60-139, with one sample (at section 100)
    # thrown 2.5 radii out: an IK/TF glitch or a pose in the wrong frame. Demonstrations get
    # such a sample dropped at fit; in a correction it used to double the canal's radius there.
    canal = line_canal()
    idx = np.arange(60, 140)
    path = canal.directrix[idx] + 0.9 * canal.radii[idx, None] * canal.normals[idx]
    spiky = path.copy()
    spiky[40] = canal.directrix[100] + 2.5 * canal.radii[100] * canal.normals[100]
    assert np.flatnonzero(correction_glitches(spiky)).tolist() == [40]
    assert not correction_glitches(path).any()
    clean = canal.corrected("include", path)
    with_glitch = canal.corrected("include", spiky)
    # The glitch is left out: the canal is the one the path without it makes...
    without = canal.corrected("include", np.delete(spiky, 40, axis=0))
    assert np.array_equal(with_glitch.radii, without.radii)
    assert np.array_equal(with_glitch.directrix, without.directrix)
    # ... no wider than the clean path's, and the correction keeps the samples as they came.
    assert (with_glitch.radii / canal.radii).max() < 1.02 * (clean.radii / canal.radii).max()
    np.testing.assert_array_equal(with_glitch.corrections[0].correction.samples, spiky)
    # An exclude's path is cleaned alike: its glitch neither cuts nor plans.
    run, pushed = pushed_run(canal, start_section=40)
    glitched = pushed.copy()
    glitched[30] = glitched[30] - 2.5 * canal.radii[70] * canal.normals[70]
    assert correction_glitches(glitched)[30]
    cut = canal.corrected("exclude", glitched)
    np.testing.assert_array_equal(cut.radii, canal.corrected("exclude", np.delete(glitched, 30, axis=0)).radii)


def test_a_correction_too_short_for_the_glitch_rule_is_taken_whole() -> None:
    # The rule needs five distinct samples to tell a glitch from motion, as for demonstrations:
    # a four-sample correction is taken as it came, whatever its shape.
    canal = line_canal()
    idx = np.array([90, 95, 100, 105])
    path = canal.directrix[idx] + 0.5 * canal.radii[idx, None] * canal.normals[idx]
    path[2] = canal.directrix[100] + 2.5 * canal.radii[100] * canal.normals[100]
    assert not correction_glitches(path).any()
    assert canal.corrected("include", path).radii[100] > 2.0 * canal.radii[100]


def test_a_correction_left_too_short_by_its_glitches_is_refused_naming_the_samples() -> None:
    # Six samples, two of them thrown five radii off: the rule drops those and the first
    # sample with them (an end whose step dwarfs the next), leaving three, fewer than a
    # correction needs, as a demonstration left that short is refused at fit.
    canal = line_canal()
    idx = np.arange(100, 124, 4)
    path = canal.directrix[idx] + 0.5 * canal.radii[idx, None] * canal.normals[idx]
    path[1:3] += 5.0 * canal.radii[idx[1:3], None] * canal.normals[idx[1:3]]
    assert correction_glitches(path).sum() == 3
    with pytest.raises(InvalidInputError, match=r"at least 4 samples in samples, got 3 after dropping 3 as glitches") as caught:
        canal.corrected("include", path)
    assert caught.value.field == "samples"


def wide_demos() -> list[np.ndarray]:
    """Four demonstrations of a 30 cm move 10 cm around its axis: fitted on 200 sections
    1.5 mm apart, a shift of half a radius needs a blend longer than the canal to stay gentle."""
    x = np.linspace(0.0, 0.3, 60)
    return [np.column_stack([x, dy + 0.004 * np.sin(20 * x + i), dz + 0.004 * np.sin(20 * x + i + 1)])
            for i, (dy, dz) in enumerate([(0.1, 0.0), (-0.1, 0.0), (0.0, 0.1), (0.0, -0.1)])]


@pytest.mark.parametrize("source", ["real UR5e demos", "wide synthetic canal"])
def test_an_exclude_over_the_middle_changes_only_its_span_and_a_bounded_blend(source: str) -> None:
    # The robot on its directrix was pushed half a radius off over sections 60-120. The cut
    # sections keep a quarter of their width, their centres moved 3/4 of a radius: blended
    # gently, that shift reached every section, moved the first one and left demonstrated
    # starts outside the canal, unmarked.
    demos = ur5e_demos()[0] if source == "real UR5e demos" else wide_demos()
    canal = canal_core.fit(demos)
    idx = np.arange(60, 121)
    pushed = canal.directrix[idx] + 0.5 * canal.radii[idx, None] * canal.normals[idx]
    refined = canal.corrected("exclude", pushed, plan=canal.directrix[idx])
    applied = refined.corrections[0]
    blend = longest_blend(canal.n_sections)
    assert blend == 18
    assert (applied.first, applied.last) == (60, 119) or (applied.first, applied.last) == (61, 119)
    assert applied.first - blend <= applied.lo and applied.hi <= applied.last + blend
    unchanged_outside(canal, refined, applied.lo, applied.hi)
    starts = np.array([d[0] for d in demos])
    assert refined.contains(starts).all()
    # Every demonstrated sample is still inside, or where the person's exclude removed the canal.
    for demo in demos:
        assert (refined.contains(demo) | refined.excluded(demo)).all()
    # Those the blend gave up on the way into the narrowed span lie in the blend, nowhere else.
    dropped = blend_dropped_crossings(canal, refined)
    rows = np.flatnonzero(dropped.any(axis=1))
    assert rows.size > 0
    world = (canal.directrix[:, None, :] + np.einsum("snk,skd->snd", canal.section_points, canal.basis))[dropped]
    assert canal.contains(world).all() and not refined.contains(world).any() and refined.excluded(world).all()
    assert np.all(((applied.lo <= rows) & (rows < applied.first)) | ((applied.last < rows) & (rows <= applied.hi)))
    # A reproduction from a demonstrated start stays in the corrected canal.
    for demo in demos:
        run = refined.reproduce(demo[0])
        assert refined.contains(run[1:]).all()


def test_the_longest_correction_on_the_finest_canal_reads_its_crossings_in_bounded_memory() -> None:
    # 20,000 samples (the most a correction takes) over 5,000 sections (the most a fit makes):
    # a table of every sample's distance to every plane took 800 MB, 1.6 GB with its temporaries.
    n, m = 5000, 20000
    x = np.linspace(0.0, 1.0, n)
    centres = np.column_stack([x, np.zeros(n), np.zeros(n)])
    tangents = np.tile([1.0, 0.0, 0.0], (n, 1))
    basis = np.tile([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], (n, 1, 1))
    t = np.linspace(-0.01, 1.01, m)
    path = np.column_stack([t, 0.02 * np.sin(400.0 * t), 0.02 * np.cos(300.0 * t)])
    tracemalloc.start()
    try:
        crossed, coords = path_crossings(path, centres, tangents, basis, np.full(n, 0.05))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 100e6, f"{peak / 1e6:.0f} MB"
    assert crossed.all()
    np.testing.assert_allclose(coords[:, 0], 0.02 * np.sin(400.0 * x), atol=2e-3)
    # Read backwards, the same crossings (the path is read as shown forwards).
    again = path_crossings(path[::-1].copy(), centres, tangents, basis, np.full(n, 0.05))
    assert np.array_equal(again[0], crossed)
