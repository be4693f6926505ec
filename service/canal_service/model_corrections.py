"""Corrections: a person refines a skill's model; each correction, and each undo, is a new
model version made on the latest (:class:`~canal_service.versions.VersionStore`).

A refit re-applies the corrections of the latest version to the new canal
(:func:`reapplied`); one that no longer applies is left behind and said so.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from functools import partial
from typing import Any

import numpy as np

import canal_core
from canal_core.corrections import Correction as Correction_
from canal_core.corrections import (
    blend_dropped_crossings,
    checked_correction,
    corrected_canal,
    correction_glitches,
)
from canal_core.routes import Routes, served_model, single_route
from canal_protocol import schemas

from .errors import CanalRejected, CorrectionNotInLatest, SkillReplaced
from .metrics import Metrics
from .storage import Correction, Database, Skill, arrays, stored_models
from .storage import repository as repo
from .validation import check_correction_inputs, check_finite_answer, check_route
from .versions import NewVersion, StoredLineage, VersionStore

#: Glitch samples a correction's note names by number; more are counted only.
GLITCHES_NAMED = 10


@dataclass(frozen=True)
class StoredCorrection:
    """A stored correction as canal_core takes it."""

    id: int
    correction: Correction_
    #: The route it corrects; None: every route (and every canal of one route).
    route: int | None = None

    @classmethod
    def of(cls, row: Correction) -> StoredCorrection:
        samples = arrays.unpack(row.samples, row.n_points, row.dim)
        times = None if row.timestamps is None else arrays.unpack(row.timestamps, row.n_points)
        quats = None if row.orientations is None else arrays.unpack(row.orientations, row.n_points, 4)
        plan = None if row.plan is None else arrays.unpack(row.plan, len(row.plan) // (8 * row.dim),
                                                           row.dim)
        return cls(row.id, Correction_(row.kind, samples, row.weight, row.label, times, quats, plan),
                   row.route)


class ModelCorrections:
    """The corrections of skills' models: make, list and undo them.

    Parameters
    ----------
    db : Database
        Storage; every query goes through ``storage.repository``.
    versions : VersionStore
        Stores each corrected model as the new latest version.
    metrics : Metrics
        The app's Prometheus metrics.
    load_routes : callable
        ``load_routes(name, version)``: (routes, version, dim) of a stored version or the
        latest (None), as the service loads it.
    """

    def __init__(self, db: Database, versions: VersionStore, metrics: Metrics,
                 load_routes: Callable[[str, int | None], tuple[Routes, int, int]]) -> None:
        self.db = db
        self.versions = versions
        self.metrics = metrics
        self.load_routes = load_routes

    def latest(self, name: str) -> list[StoredCorrection]:
        """The corrections of the skill's latest model version, in the order applied."""
        with self.db.read() as s:
            skill = repo.get_skill(s, name)
            _version, ids = repo.latest_corrections(s, skill)
            return [StoredCorrection.of(r) for r in repo.get_corrections(s, skill, ids)]

    def _store_refined(self, name: str, options: dict[str, Any], demo_ids: list[int],
                       routes: Routes, lineage: StoredLineage, notes: list[str], *,
                       instance: str, base: int | None
                       ) -> tuple[schemas.ModelSummary, Callable[[], None]]:
        """Store a refined model as the new latest version of the skill ``instance``, made on
        ``base`` (:meth:`VersionStore.store`); what to tell once stored, as
        :meth:`VersionStore.on_latest` takes it."""
        (stored,) = self.versions.store(name, [NewVersion(
            options, demo_ids, served_model(routes).to_dict(), 0.0, routes, lineage)],
            instance=instance, base=base)
        stored.summary.notes = notes
        return stored.summary, partial(self.versions.tell, name, stored)

    def correct(self, name: str, body: schemas.CorrectionIn, *,
                instance: str | None = None) -> schemas.CorrectedModel:
        """Refine a model version (the latest by default) by a person's correction; the
        result is the new latest version. Nothing is stored when canal_core refuses it.
        ``instance``: the skill a live capture began on (:func:`repo.skill_instance`); the
        correction refines that skill only (:class:`SkillReplaced`).

        The latest is the latest when the correction is stored: a fit, correction or undo
        that lands meanwhile is what it is applied to (a version the request names is
        corrected whatever landed since)."""
        version = None if body.model == "latest" else int(body.model)
        made: list[Correction] = []

        def build() -> tuple[schemas.ModelSummary, Callable[[], None]]:
            if instance is not None:  # before a deleted skill's "not found"
                with self.db.read() as s:
                    repo.skill_of_instance(s, name, "correction", instance)
            routes, base_version, dim = self.load_routes(name, version)
            route = check_route(body.route, routes.n_routes, "route")
            canal = routes.pooled if route is None else routes.canals[route]
            with self.db.read() as s:
                skill = repo.get_skill(s, name)
                now = repo.skill_instance(skill.id, skill.created_at)
                if instance is not None and now != instance:
                    raise SkillReplaced(name, "correction", exists=True)
                base = repo.get_model(s, repo.require_model_ref(s, skill, base_version)[0])
                lineage = repo.lineages(s, [base])[base.id]
                options, demo_ids = dict(base.options), list(base.demo_ids)
            check_correction_inputs(canal.directrix, canal.radii, body.samples, body.plan,
                                    body.timestamps)
            try:
                correction = checked_correction(body.kind, body.samples, dim, body.weight,
                                                body.label, body.timestamps, body.orientations,
                                                body.plan)
                refined, applied = corrected_routes(routes, correction, route)
            except canal_core.CanalError as exc:
                raise CanalRejected(exc, exc.message, field=exc.field) from exc
            for each in refined.every_canal:
                check_finite_answer({"directrix": each.directrix, "radii": each.radii},
                                    "samples, plan")

            def store(s: Any, skill: Skill, version: int, ids: list[int]) -> list[int]:
                row = repo.insert_correction(
                    s, skill, correction.kind, correction.label, correction.weight,
                    correction.samples, correction.timestamps, correction.orientations,
                    correction.plan, base_version, version, applied.first, applied.last, route)
                made.append(row)
                return [*ids, row.id]

            return self._store_refined(
                name, options, demo_ids, refined,
                StoredLineage(base_version, lineage.fit_version, lineage.correction_ids, store),
                _glitch_notes(correction.samples) + _blend_notes(routes, refined), instance=now,
                base=base_version if version is None else None)

        summary = self.versions.on_latest(name, "correction", build)
        row = made[-1]
        self.metrics.corrections.labels(row.kind).inc()
        return schemas.CorrectedModel(**summary.model_dump(),
                                      correction=_correction_out(row, undone=False))

    def list_corrections(self, name: str, offset: int, limit: int
                         ) -> schemas.Page[schemas.CorrectionOut]:
        """A page of the skill's corrections, oldest first; those the latest version does
        not hold say they are undone."""
        with self.db.read() as s:
            skill = repo.get_skill(s, name)
            _version, held = repo.latest_corrections(s, skill)
            rows, total = repo.list_corrections(s, skill, offset, limit)
            items = [_correction_out(r, undone=r.id not in held) for r in rows]
        return schemas.Page[schemas.CorrectionOut](items=items, total=total, offset=offset,
                                                    limit=limit)

    def get_correction(self, name: str, correction_id: int) -> schemas.CorrectionPath:
        """One correction of the skill with its path (:class:`CorrectionNotFound`)."""
        with self.db.read() as s:
            skill = repo.get_skill(s, name)
            _version, held = repo.latest_corrections(s, skill)
            row = repo.get_corrections(s, skill, [correction_id])[0]
            out = _correction_out(row, undone=row.id not in held)
            return schemas.CorrectionPath(**out.model_dump(), **stored_models.path_of(row))

    def undo_correction(self, name: str, correction_id: int) -> schemas.CorrectedModel:
        """A new latest version without one correction: the others re-applied to the fit.

        The others are those of the latest version when the undo is stored: a correction
        that lands meanwhile is kept."""
        undone: list[Correction] = []

        def build() -> tuple[schemas.ModelSummary, Callable[[], None]]:
            with self.db.read() as s:
                skill = repo.get_skill(s, name)
                instance = repo.skill_instance(skill.id, skill.created_at)
                target = repo.get_corrections(s, skill, [correction_id])[0]
                ref = repo.require_model_ref(s, skill, None)
                latest = repo.get_model(s, ref[0])
                lineage = repo.lineages(s, [latest])[latest.id]
                if correction_id not in lineage.correction_ids:
                    raise CorrectionNotInLatest(
                        f"correction {correction_id} is not part of the latest model version "
                        f"{latest.version} of skill {name!r} (undone already, or left behind by "
                        "a refit)", field="id")
                rest = [StoredCorrection.of(r) for r in repo.get_corrections(
                    s, skill, [i for i in lineage.correction_ids if i != correction_id])]
                options, demo_ids = dict(latest.options), list(latest.demo_ids)
                latest_version = latest.version
            base, _v, _dim = self.load_routes(name, lineage.fit_version)
            refined, applied, notes = reapplied(base, rest)
            undone.append(target)
            return self._store_refined(
                name, options, demo_ids, refined,
                StoredLineage(latest_version, lineage.fit_version, [c.id for c in applied]),
                notes, instance=instance, base=latest_version)

        summary = self.versions.on_latest(name, "undo", build)
        self.metrics.corrections_undone.inc()
        return schemas.CorrectedModel(**summary.model_dump(),
                                      correction=_correction_out(undone[-1], undone=True))


def reapplied(routes: Routes, kept: Sequence[StoredCorrection]
              ) -> tuple[Routes, list[StoredCorrection], list[str]]:
    """``routes`` with each correction re-applied in turn (to the route its samples lie
    along, or to every canal it passes through: :func:`corrected_routes`), those applied
    (with the route they went to) and notes; those that fail are skipped."""
    applied, notes = [], []
    for stored in kept:
        route = stored.route
        if route is not None and routes.n_routes > 1:
            route = canal_core.routes.way_of(routes, stored.correction.samples, keep=route)
            if route != stored.route:
                notes.append(f"correction {stored.id} follows its way: route {stored.route} "
                             f"is now route {route}")
        try:
            routes, _first = corrected_routes(routes, stored.correction, route)
        except canal_core.CanalError as exc:
            notes.append(f"correction {stored.id} no longer applies and was left out: "
                         f"{exc.message}")
            continue
        applied.append(replace(stored, route=route))
    return routes, applied, notes


def corrected_routes(routes: Routes, correction: Correction_, route: int | None
                     ) -> tuple[Routes, Any]:
    """``routes`` refined by ``correction``, and the first route's applied correction (the
    canal of all's when no route took it).

    One route: its canal, as a single-canal model (``route`` is 0 or None). Several:
    ``route`` names the one canal corrected; None corrects every canal the samples pass
    through (each route's and the canal of all), refused when no route's canal takes it.
    """
    if routes.n_routes == 1:
        refined = corrected_canal(routes.pooled, correction)
        return single_route(refined), refined.corrections[-1]
    canals = list(routes.canals)
    if route is not None:
        canals[route] = corrected_canal(canals[route], correction)
        return Routes(tuple(canals), routes.pooled, routes.labels), canals[route].corrections[-1]
    taken: list[Any] = []
    refusals: dict[int, canal_core.CanalError] = {}
    for k, canal in enumerate(canals):
        try:
            canals[k] = corrected_canal(canal, correction)
        except canal_core.CanalError as exc:
            refusals[k] = exc
            continue
        taken.append(canals[k].corrections[-1])
    if not taken:
        raise _refused_by_every_route(refusals, routes.pooled, correction)
    try:
        pooled = corrected_canal(routes.pooled, correction)
    except canal_core.CanalError:
        pooled = routes.pooled  # a path along one route may leave the canal of all
    # The span stored is a route's (the first that took it): the canal of all is followed by
    # no reproduction, and its sections are not the ones a person corrected.
    return Routes(tuple(canals), pooled, routes.labels), taken[0]


def _refused_by_every_route(refusals: dict[int, canal_core.CanalError],
                            pooled: canal_core.Canal, correction: Correction_
                            ) -> canal_core.CanalError:
    """The refusal of a correction no route's canal takes. The canal of all may still hold
    it (a path between the routes), but no reproduction or live stream follows that canal:
    a correction of it alone would change nothing a robot does."""
    tried = "; ".join(f"route {k}: {exc.message}" for k, exc in sorted(refusals.items()))
    try:
        corrected_canal(pooled, correction)
        between = (", though the canal of all the demonstrations holds it (which no "
                   "reproduction or live stream follows)")
    except canal_core.CanalError:
        between = ""
    fields = {exc.field for exc in refusals.values()}
    field = fields.pop() if len(fields) == 1 and None not in fields else "samples"
    return canal_core.InvalidInputError(
        f"expected a path that one route's canal takes, got one that none of routes "
        f"{', '.join(map(str, sorted(refusals)))} takes{between} ({tried}); show it along the "
        "way the robot goes, or name that way with `route`", field=field)


def _correction_out(row: Correction, *, undone: bool) -> schemas.CorrectionOut:
    """A stored correction as answered; ``undone``: the skill's latest version does not hold
    it (an undo, a refit that left it behind or did not keep it, or a correction of a version
    made before it)."""
    return schemas.CorrectionOut(
        id=row.id, kind=row.kind, label=row.label, weight=row.weight, n_points=row.n_points,
        base_version=row.base_version, model_version=row.model_version,
        first_section=row.first_section, last_section=row.last_section,
        created_at=row.created_at, undone=undone, route=row.route)


def _glitch_notes(samples: arrays.FloatArray) -> list[str]:
    """A note on the samples of a correction path left out as glitches (none: no note)."""
    rows = np.flatnonzero(correction_glitches(samples)).tolist()
    if not rows:
        return []
    named = ", ".join(map(str, rows[:GLITCHES_NAMED])) + (", ..." if len(rows) > GLITCHES_NAMED else "")
    one = len(rows) == 1
    return [f"{len(rows)} of the {samples.shape[0]} samples {'was' if one else 'were'} left out as "
            f"{'a glitch' if one else 'glitches'} (far off the path and straight back, the rule "
            f"demonstrations are cleaned by at fit): sample{'' if one else 's'} {named}"]


def _blend_notes(routes: Routes, refined: Routes) -> list[str]:
    """A note per corrected canal whose blend, on the way into an exclude's narrowed span,
    leaves demonstrated crossings outside it; none when it leaves none."""
    notes = []
    for k, (old, new) in enumerate(zip(routes.every_canal, refined.every_canal, strict=True)):
        if len(new.corrections) == len(old.corrections):
            continue  # a canal the correction did not change
        lost = blend_dropped_crossings(old, new)
        if not lost.any():
            continue
        rows, first = np.flatnonzero(lost.any(axis=1)), new.corrections[-1].first
        where = " and ".join(f"{side[0]}..{side[-1]}" for side in (rows[rows < first], rows[rows > first])
                             if side.size)
        which = "" if refined.n_routes == 1 else (" of the canal of all" if k == 0 else f" of route {k - 1}")
        notes.append(f"{int(lost.sum())} demonstrated crossings in sections {where}{which}, where the "
                     "canal narrows into the exclude's span, are outside the corrected canal: "
                     "excluded by this correction, as those on its excluded side are")
    return notes


__all__: Sequence[str] = ["ModelCorrections", "StoredCorrection", "corrected_routes",
                          "reapplied"]
