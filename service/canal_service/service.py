"""The service layer: the only place that combines storage, canal_core and the recorder.

Routes call these methods (in a worker thread: every method here may block on the database
or on numpy). Each method runs in one transaction, so a failure stores nothing; the recorder
hears about a change only after it committed.
"""

from __future__ import annotations

import logging
import os
import re
import socket
import threading
import time
from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path
from typing import Any, Literal, Protocol

import numpy as np
import numpy.typing as npt

import canal_core
from canal_core.routes import RouteChoice, Routes, routes_from_dict, served_model, single_route
from canal_protocol import schemas
from canal_protocol.options import RecordingKind

from . import uploads
from .errors import (
    CanalRejected,
    Disabled,
    InvalidInput,
    ModelVersionNotFound,
    NotEnoughDemonstrations,
    RecordingFailed,
    ReproductionCancelled,
    ReproductionTooSlow,
    SkillNotFound,
)
from .fitting import FitJob, FitRunner
from .listeners import FitListeners, SceneListeners
from .metrics import Metrics
from .model_cache import CanalCache, model_cache_key
from .model_corrections import ModelCorrections, reapplied
from .storage import Database, Demonstration, ModelVersion, Skill, arrays
from .storage import repository as repo
from .validation import (
    DemoArrays,
    check_demonstration,
    check_finite_answer,
    check_obstacles,
    check_reproduction_inputs,
    check_route,
    check_timestamps,
)
from .versions import NewVersion, StoredLineage, VersionStore, model_summary

log = logging.getLogger("canal_service")

#: Which model: (its skill's creation time in ns, its version).
Revision = tuple[int, int]
#: Which replica answered (host and process), as exports name it.
REPLICA = f"{socket.gethostname()}:{os.getpid()}"


class RecorderLike(Protocol):
    """What the service, its routes and the live path call on the recorder.

    ``canal_service.recording.Recorder`` is checked against it where ``create_app`` builds
    one. Record methods (``demo_added`` ... ``live``) only queue and promise never to raise.
    """

    def demo_added(self, skill: str, dim: int, demo_id: int, positions: npt.ArrayLike,
                   timestamps: npt.ArrayLike | None, label: str | None) -> None: ...
    def demo_removed(self, skill: str, demo_id: int, *, instance: str | None = None) -> None: ...
    def model_fitted(self, skill: str, version: int, canal: canal_core.Canal | Routes, *,
                     t_ns: int | None = None, instance: str | None = None) -> None: ...
    def reproduction(self, skill: str, version: int, result: canal_core.Reproduction, *,
                     number: int | None = None, t_ns: int | None = None,
                     instance: str | None = None) -> None: ...
    def live(self, skill: str, robot: str, position: npt.ArrayLike,
             target: canal_core.TrackerTarget, t_ns: int | None = None,
             orientation: npt.ArrayLike | None = None) -> None: ...
    def scene_changed(self, skill: str, version: int, obstacles: list[dict[str, Any]],
                      dim: int, *, instance: str | None = None) -> None: ...
    def skill_deleted(self, skill: str) -> None: ...
    def export_rrd(self, skill: str) -> Path: ...
    def export_mcap(self, skill: str, profile: str = "foxglove") -> Path: ...
    def rebuild(self, skill: str, timeout_s: float | None = None) -> dict[str, Any]: ...
    def health(self) -> dict[str, Any]: ...
    def close(self) -> None: ...


def _tolist(value: Any) -> Any:
    return None if value is None else np.asarray(value, dtype=np.float64).tolist()


# A demonstration this many times larger or smaller than the median one is named in the fit's
# notes: people's demonstrations of one skill differ by a few times, units by 10 to 1000.
UNIT_SUSPECT_RATIO = 20.0
#: (ratio, smaller unit, larger unit) of the unit mix-ups a size ratio points to.
_UNIT_PAIRS = ((1000.0, "millimetres", "metres"), (100.0, "centimetres", "metres"),
               (10.0, "millimetres", "centimetres"))


def unit_notes(positions: list[arrays.FloatArray], demo_ids: list[int]) -> list[str]:
    """A note for each demonstration whose size is far from the median's: its units are
    likely not the others' (a fit cannot tell that from a way of its own)."""
    notes = []
    for demo_id, ratio in zip(demo_ids, canal_core.preprocess.size_ratios(positions), strict=True):
        if 1.0 / UNIT_SUSPECT_RATIO < ratio < UNIT_SUSPECT_RATIO:
            continue
        larger = ratio >= 1.0
        factor = ratio if larger else 1.0 / ratio
        hint = next((f"{small} among {big}" if larger else f"{big} among {small}"
                     for scale, small, big in _UNIT_PAIRS
                     if 0.8 * scale <= factor <= 1.25 * scale), None)
        size = (f"{factor:.0f} times the size of" if larger
                else f"1/{factor:.0f} of the size of")
        notes.append(f"demonstration {demo_id} is {size} the median demonstration: check its "
                     "units" + (f" ({hint}?)" if hint else "")
                     + ", or delete it if it was a slip")
    return notes


class CanalService:
    """Use cases of the REST API, independent of HTTP.

    Model versions are made and stored by its :class:`VersionStore` (``versions``), the
    corrections of models by its :class:`ModelCorrections` (``corrections``).

    Parameters
    ----------
    db : Database
        Storage; every query goes through ``storage.repository``.
    metrics : Metrics
        The app's Prometheus metrics.
    cache_size : int
        Decoded canals kept in memory.
    recorder : RecorderLike, optional
        Hears of every committed change; None when recordings are off.
    fit_listeners : FitListeners, optional
        Told of every committed fit (the live bridge subscribes); a fresh empty set if None.
    reproductions_kept : int
        With a recorder, reproductions are stored for the recordings, this many per skill
        (the newest); 0 stores none.
    fits : FitRunner, optional
        Runs fits in worker processes within their server-time cap (120 s if None).
    """

    def __init__(self, db: Database, metrics: Metrics, *, cache_size: int = 64,
                 recorder: RecorderLike | None = None,
                 fit_listeners: FitListeners | None = None,
                 reproductions_kept: int = 1000,
                 fits: FitRunner | None = None, reproduce_max_seconds: float = 30.0) -> None:
        self.fits = fits if fits is not None else FitRunner(120.0)
        self.reproduce_max_seconds = float(reproduce_max_seconds)
        self.db = db
        self.reproductions_kept = int(reproductions_kept)
        self.metrics = metrics
        self.recorder = recorder
        self.cache = CanalCache(cache_size)
        self.fit_listeners = fit_listeners if fit_listeners is not None else FitListeners()
        self.scene_listeners = SceneListeners()
        self.versions = VersionStore(db, self.cache, self.fit_listeners, self._record)
        self.corrections = ModelCorrections(db, self.versions, metrics, self.load_routes)

    # ---- recorder ---------------------------------------------------------------------------

    def _record(self, what: str, call: Callable[[RecorderLike], None]) -> None:
        # The recorder promises never to raise; a broken one must still not fail a request
        # whose data is already committed.
        if self.recorder is None:
            return
        try:
            call(self.recorder)
        except Exception:
            log.exception("recorder.%s failed", what)

    # ---- skills -----------------------------------------------------------------------------

    def create_skill(self, body: schemas.SkillCreate) -> schemas.SkillOut:
        """Create a skill (:class:`SkillExists` when the name is taken)."""
        with self.db.write() as s:
            skill = repo.create_skill(s, body.name, body.description, body.dim)
            return self._skill_out(skill, repo.SkillStats(0, 0, None))

    def get_skill(self, name: str) -> schemas.SkillOut:
        """A skill with its counts."""
        with self.db.read() as s:
            skill = repo.get_skill(s, name)
            return self._skill_out(skill, repo.skill_stats(s, [skill.id])[skill.id])

    def list_skills(self, offset: int, limit: int) -> schemas.Page[schemas.SkillOut]:
        """A page of skills with counts."""
        with self.db.read() as s:
            skills, total = repo.list_skills(s, offset, limit)
            stats = repo.skill_stats(s, [k.id for k in skills])
            items = [self._skill_out(k, stats[k.id]) for k in skills]
        return schemas.Page[schemas.SkillOut](items=items, total=total, offset=offset, limit=limit)

    def delete_skill(self, name: str) -> None:
        """Delete a skill with its demonstrations and models."""
        with self.db.write() as s:
            repo.delete_skill(s, name)
        self.fits.cancel_skill(name)
        # The bridge stops serving it now, as it serves a fit now: its robots are answered
        # unknown_skill from their next pose, not steered by a deleted canal until a refresh.
        self.fit_listeners.notify(name, 0, None)
        self._record("skill_deleted", lambda r: r.skill_deleted(name))

    @staticmethod
    def _skill_out(skill: Skill, stats: repo.SkillStats) -> schemas.SkillOut:
        return schemas.SkillOut(
            name=skill.name, description=skill.description, dim=skill.dim,
            created_at=skill.created_at, n_demonstrations=stats.n_demonstrations,
            n_models=stats.n_models, latest_model_version=stats.latest_model_version,
        )

    def skill_dim(self, name: str) -> int:
        """The skill's dimension (:class:`SkillNotFound` for an unknown skill)."""
        with self.db.read() as s:
            return repo.get_skill(s, name).dim

    # ---- demonstrations ---------------------------------------------------------------------

    def add_json_demonstration(self, name: str, body: schemas.DemonstrationIn,
                               time_unit: str | None = None) -> schemas.DemonstrationCreated:
        """Check and store a demonstration sent as JSON (``time_unit``: of its timestamps).

        Rows 2 or 3 wide are checked at their own width and compared with the skill's
        inside the storing transaction (no separate lookup on the hot path).
        """
        first = body.positions[0] if len(body.positions) else None  # lists or arrays
        dim = len(first) if first is not None and len(first) in (2, 3) else self.skill_dim(name)
        demo = check_demonstration(body.positions, dim, body.timestamps, body.orientations,
                                   time_unit)
        return self.add_demonstration(name, demo, body.label, "json")

    def add_file_demonstration(self, name: str, fmt: uploads.UploadFormat, data: bytes,
                               topic: str | None, label: str | None,
                               limits: uploads.UploadLimits | None = None,
                               time_unit: str | None = None,
                               ) -> schemas.DemonstrationCreated:
        """Parse (within ``limits``), check and store a demonstration uploaded as a file;
        ``time_unit`` is the unit of a CSV or NPY time column."""
        demo = self.read_file(name, fmt, data, topic, limits, time_unit)
        return self.add_demonstration(name, demo, label, fmt)

    def read_file(self, name: str, fmt: uploads.UploadFormat, data: bytes, topic: str | None,
                  limits: uploads.UploadLimits | None = None, time_unit: str | None = None,
                  fittable: bool = True) -> DemoArrays:
        """The checked arrays of a file sent for the skill, parsed within ``limits`` for the
        skill's dimension: a demonstration, or (``fittable=False``) a correction's path."""
        if fmt == "mcap" and time_unit is not None:
            raise InvalidInput("time_unit applies to a CSV or NPY time column; an MCAP "
                               "file's times are read from its message stamps", field="time_unit")
        dim = self.skill_dim(name)
        parsed = uploads.parse_upload(fmt, data, dim, topic, limits)
        return check_demonstration(parsed.positions, dim, parsed.timestamps, parsed.orientations,
                                   time_unit if time_unit is not None else parsed.time_unit,
                                   fittable)

    def add_demonstration(self, name: str, demo: DemoArrays, label: str | None,
                          source: str, *, instance: str | None = None
                          ) -> schemas.DemonstrationCreated:
        """Store a checked demonstration; its dimension was checked against the skill's.
        ``instance``: the skill a live capture began on (:func:`repo.skill_instance`); the
        demonstration goes into that skill only (:class:`SkillReplaced`)."""
        stored = repo.insert_demonstration(
            self.db, name, demo.positions, demo.timestamps, demo.orientations, label, source,
            captured_on=None if instance is None else ("demonstration", instance))
        created = schemas.DemonstrationCreated(id=stored.id, n_points=stored.n_points,
                                               checksum=stored.checksum)
        dim = stored.dim
        self.metrics.demos_stored.labels(source).inc()
        self._record("demo_added", lambda r: r.demo_added(name, dim, created.id, demo.positions,
                                                          demo.timestamps, label))
        return created

    def list_demonstrations(self, name: str, offset: int, limit: int
                            ) -> schemas.Page[schemas.DemonstrationSummary]:
        """A page of demonstration summaries."""
        with self.db.read() as s:
            skill = repo.get_skill(s, name)
            rows, total, flags = repo.list_demonstrations(s, skill, offset, limit)
            items = [self._demo_summary(r, *flags.get(r.id, (False, False))) for r in rows]
        return schemas.Page[schemas.DemonstrationSummary](items=items, total=total,
                                                           offset=offset, limit=limit)

    def get_demonstration(self, name: str, demo_id: int) -> schemas.DemonstrationOut:
        """One demonstration with its arrays."""
        with self.db.read() as s:
            skill = repo.get_skill(s, name)
            row = repo.get_demonstration(s, skill, demo_id)
            positions, times, quats = _demo_arrays(row)
            summary = self._demo_summary(row, times is not None, quats is not None)
        return schemas.DemonstrationOut(
            **summary.model_dump(), positions=positions.tolist(), timestamps=_tolist(times),
            orientations=_tolist(quats),
        )

    def delete_demonstration(self, name: str, demo_id: int) -> None:
        """Delete one demonstration (fitted models keep their record of it)."""
        with self.db.write() as s:
            skill = repo.get_skill(s, name)
            repo.delete_demonstration(s, skill, demo_id)
            instance = repo.skill_instance(skill.id, skill.created_at)
        self._record("demo_removed", lambda r: r.demo_removed(name, demo_id, instance=instance))

    @staticmethod
    def _demo_summary(row: Demonstration, has_t: bool, has_q: bool
                      ) -> schemas.DemonstrationSummary:
        return schemas.DemonstrationSummary(
            id=row.id, label=row.label, n_points=row.n_points, dim=row.dim,
            has_timestamps=has_t, has_orientations=has_q, source=row.source,
            checksum=row.checksum, created_at=row.created_at,
        )

    # ---- fitting ----------------------------------------------------------------------------

    def fit(self, name: str, body: schemas.FitRequest,
            cancel: threading.Event | None = None) -> schemas.ModelSummary:
        """Fit a new model version from the skill's demonstrations (or the chosen ones).

        The fit runs in a worker process within ``CANAL_FIT_MAX_SECONDS``; it stops when
        ``cancel`` is set (the client left) or the skill is deleted meanwhile.
        """
        with self.db.read() as s:
            skill = repo.get_skill(s, name)
            instance = repo.skill_instance(skill.id, skill.created_at)
            rows = repo.demonstrations_for_fit(s, skill, body.demo_ids)
            loaded = [(r.id, *_demo_arrays(r)) for r in rows]
            # what the refit will re-apply, for its cost estimate (those of the latest version
            # when it lands are re-applied: one made meanwhile is not counted)
            kept_points = (repo.correction_points(s, skill, repo.latest_corrections(s, skill)[1])
                           if body.keep_corrections else [])
        if body.demo_ids is not None:
            missing = sorted(set(body.demo_ids) - {d[0] for d in loaded})
            if missing:
                raise InvalidInput(f"skill {name!r} has no demonstrations {missing}",
                                   field="demo_ids")
        if len(loaded) < 2:
            raise NotEnoughDemonstrations(
                f"fitting needs at least 2 demonstrations, skill {name!r} has {len(loaded)}"
                + (" selected" if body.demo_ids is not None else ""),
                field="demonstrations",
            )
        demo_ids = [d[0] for d in loaded]
        positions = [d[1] for d in loaded]
        times = [d[2] for d in loaded]
        options = body.model_dump(exclude={"demo_ids", "by_time", "orientation", "keep_corrections",
                                           "routes", "route_separation"})
        # Time stamps always give the model its speed profile; what aligns is by_time's or the
        # fit's timing test's choice, answered as the model's clock.
        stamped = times if any(t is not None for t in times) else None
        quats = [d[3] for d in loaded]
        # Orientation is learned only when every demo has it: a mean over some demos would
        # not be the skill's.
        orientations = quats if body.orientation and all(q is not None for q in quats) else None
        started = time.perf_counter()
        labels, route_notes = self._route_labels(positions, body.routes, body.route_separation,
                                                 demo_ids)
        route_notes = unit_notes(positions, demo_ids) + route_notes
        unstamped = [i for i, t in zip(demo_ids, times, strict=True) if t is None]
        if body.by_time and unstamped:  # time needs every one stamped (canal_core.clocks)
            route_notes.append(
                f"by_time asked, but demonstration{'s' if len(unstamped) > 1 else ''} "
                f"{', '.join(map(str, unstamped))} {'have' if len(unstamped) > 1 else 'has'} no "
                "time stamps: aligned by arc length (upload them with their time, or fit "
                "only the stamped ones with demo_ids)")
        job = FitJob(positions, stamped, body.by_time, orientations, options, labels, kept_points)
        try:
            fitted = self.fits.run(name, job, cancel)
        except canal_core.CanalError as exc:
            raise _fit_rejected(exc, demo_ids) from exc
        seconds = time.perf_counter() - started
        routes = fitted if isinstance(fitted, Routes) else single_route(fitted)
        canal = routes.pooled
        for each in routes.every_canal:
            check_finite_answer({"directrix": each.directrix, "radii": each.radii,
                                 "tangents": each.tangents, "arclength": each.arclength},
                                "demonstrations")
        serialized = fitted.to_dict()
        used_options = {**canal.options.to_dict(), "by_time": canal.clock in ("time", "time+arc"),
                        "clock": canal.clock, "orientation": bool(canal.has_orientation)}
        if routes.n_routes > 1:
            used_options.update(routes=routes.n_routes, route_separation=body.route_separation,
                                demo_routes=routes.labels.tolist())
        plain = NewVersion(used_options, demo_ids, serialized, seconds, routes)

        def build() -> tuple[schemas.ModelSummary, Callable[[], None]]:
            # The corrections kept are those of the latest version when the fit is stored,
            # not when it started: one a person made while the fit ran is re-applied too.
            kept = self.corrections.latest(name) if body.keep_corrections else None
            if not kept:
                (fit,) = self.versions.store(name, [plain], kept=None if kept is None else [],
                                             instance=instance)
                fit.summary.notes = route_notes
                return fit.summary, partial(self.versions.tell, name, fit)
            # The skill's corrections, re-applied to the new canal (a version of its own, whose
            # parent is the plain fit); one that no longer applies is left behind and said so.
            refined, applied, notes = reapplied(routes, kept)
            made_on = {c.id: c.route for c in kept}
            moved = {c.id: c.route for c in applied if c.route != made_on[c.id]}

            def follow(s: Any, skill: Skill, _version: int, ids: list[int]) -> list[int]:
                # a correction that followed its way to another route number keeps that number
                for row in repo.get_corrections(s, skill, list(moved)):
                    row.route = moved[row.id]
                return ids

            lineage = StoredLineage(None, None, [c.id for c in applied], follow if moved else None)
            fit, corrected = self.versions.store(name, [plain, NewVersion(
                used_options, demo_ids, served_model(refined).to_dict(), 0.0, refined, lineage)],
                kept=[c.id for c in kept], instance=instance)
            corrected.summary.notes = route_notes + notes

            def tell() -> None:
                self.versions.tell(name, fit, notify=False)
                self.versions.tell(name, corrected)

            return corrected.summary, tell

        summary = self.versions.on_latest(name, "fit", build)
        self.metrics.fits.inc()
        self.metrics.fit_seconds.observe(seconds)
        return summary

    def _route_labels(self, positions: list[arrays.FloatArray], routes: int | None,
                      separation: float, demo_ids: list[int]
                      ) -> tuple[list[int] | None, list[str]]:
        """The route of each demonstration (None when the fit is one canal: ``routes`` 1, or
        the demonstrations all go one way) and notes on the demonstrations that went a way
        of their own alone. Clustering runs here, before the fit's cost is estimated, so the
        estimate counts every route's fit."""
        if routes == 1:
            return None, []
        try:
            canal_core.options.route_options(routes, separation)
            self.fits.check_route_cost(len(positions), int(positions[0].shape[1]))
            split = canal_core.routes.route_split(positions, routes, separation)
        except canal_core.CanalError as exc:
            raise CanalRejected(exc, exc.message, field=exc.field) from exc
        labels = split.labels
        copies = {group[0]: group for group in split.repeats}

        def named(group: tuple[int, ...]) -> str:
            ids = [str(demo_ids[i]) for i in group]
            return f"{', '.join(ids[:-1])} and {ids[-1]}"

        notes: list[str] = []
        later = {i for group in split.repeats for i in group[1:]}
        for j in (i for i in split.joined if i not in later):
            if j in copies:
                notes.append(f"demonstrations {named(copies.pop(j))} are identical: they show one way "
                             "once, and no route has two different demonstrations to lend it a width, "
                             f"so they joined route {int(labels[j])} (and widen it): show that way "
                             "again (not the same file) to learn it as a route, or delete the repeats")
                continue
            notes.append(f"demonstration {demo_ids[j]} goes a way of its own; no route has two "
                         "different demonstrations to lend it a width, so it joined route "
                         f"{int(labels[j])} (and widens it): show that way once more to learn it as "
                         "a route, or delete it")
        for j, donor in zip(split.lone, split.donors, strict=True):
            if j in copies:
                notes.append(f"demonstrations {named(copies.pop(j))} are identical: route "
                             f"{int(labels[j])} shows its way once, with the width of route {donor} "
                             "in proportion to its length; show that way again (not the same file) "
                             "to learn its own width, or delete the repeats")
                continue
            notes.append(f"demonstration {demo_ids[j]} goes a way of its own alone: it is route "
                         f"{int(labels[j])}, with the width of route {donor} in proportion to its "
                         "length (one demonstration shows a way, not how far it strays): show that way "
                         "once more to learn its own width, or delete it if it was a slip")
        # Copies that another way joined: their route's width is only what that way adds.
        notes.extend(f"demonstrations {named(group)} are identical: they show the way of route "
                     f"{int(labels[group[0]])} once, and its width comes only from the way that "
                     "joined it; show that way again (not the same file), or delete the repeats"
                     for group in copies.values())
        return (None if int(labels.max(initial=0)) == 0 else [int(v) for v in labels]), notes

    def list_models(self, name: str, offset: int, limit: int) -> schemas.Page[schemas.ModelSummary]:
        """A page of model versions, newest first."""
        with self.db.read() as s:
            skill = repo.get_skill(s, name)
            rows, total = repo.list_models(s, skill, offset, limit)
            found = repo.lineages(s, rows)
            items = [model_summary(r, skill.dim, found[r.id]) for r in rows]
        return schemas.Page[schemas.ModelSummary](items=items, total=total, offset=offset,
                                                   limit=limit)

    def load_canal(self, name: str, version: int | None
                   ) -> tuple[canal_core.Canal, ModelVersion | None, int, int]:
        """(canal, row or None when served from cache, version, dim) of a version or the latest.

        One query finds the row (no ORM); the canal comes from the cache, or from the row,
        decoded once. Nothing about "latest" is cached: another replica may have fitted.
        Raises :class:`SkillNotFound`, :class:`NoModelYet` (latest of a skill never fitted)
        or :class:`ModelVersionNotFound`.
        """
        routes, row, ref = self._load_routes(name, version)
        return routes.pooled, row, ref.version, ref.dim

    def load_routes(self, name: str, version: int | None
                    ) -> tuple[Routes, int, int]:
        """(routes, version, dim) of a version or the latest: every stored model as
        :class:`Routes` (a single canal is one route, :func:`single_route`)."""
        routes, _row, ref = self._load_routes(name, version)
        return routes, ref.version, ref.dim

    def _load_routes(self, name: str, version: int | None
                     ) -> tuple[Routes, ModelVersion | None, repo.ModelRef]:
        """The one loader of stored models: (routes, row or None when served from cache, the
        row's reference: its skill's id and creation time)."""
        ref = repo.model_ref_by_name(self.db, name, version)
        key = model_cache_key(ref.model_id, ref.skill_created_at)
        routes = self.cache.get(key)
        row = None
        if routes is None:
            with self.db.read() as s:
                row = repo.get_model(s, ref.model_id)
                if (row.skill_id, row.version) != (ref.skill_id, ref.version):
                    # Deleted and its id reused between the two queries: not the row found.
                    raise ModelVersionNotFound(
                        f"model version {ref.version} of skill {name!r} was deleted meanwhile",
                        field="model")
                data = repo.model_canal(s, row)
            routes = routes_from_dict(data)
            self.cache.put(key, routes)
        return routes, row, ref

    def latest_revision(self, name: str) -> Revision:
        """(the skill's creation time in ns, its latest model version), from one query (no
        canal read or decoded). The creation time tells a skill deleted and created again
        under its name, whose versions start again at 1, from the one before. Raises
        :class:`SkillNotFound` or :class:`NoModelYet`."""
        return _revision(repo.model_ref_by_name(self.db, name, None))

    def latest_model(self, name: str) -> tuple[Routes, Revision, int]:
        """(routes, revision as :meth:`latest_revision` says it, dim) of the latest model."""
        routes, _row, ref = self._load_routes(name, None)
        return routes, _revision(ref), ref.dim

    def skills_by_latest_fit(self, limit: int) -> list[tuple[str, int]]:
        """(skill, latest version) of at most ``limit`` skills with a model, most recently
        fitted first (the live bridge preloads these at start)."""
        if limit <= 0:
            return []
        with self.db.read() as s:
            return repo.skills_by_latest_fit(s, limit)

    def get_model(self, name: str, version: int | None, serialized: bool) -> schemas.ModelOut:
        """A model version with its geometry."""
        with self.db.read() as s:
            skill = repo.get_skill(s, name)
            row = repo.get_model(s, repo.require_model_ref(s, skill, version)[0])
            dim, skill_created_at = skill.dim, skill.created_at
            lineage = repo.lineages(s, [row])[row.id]
            key = model_cache_key(row.id, skill_created_at)
            routes = self.cache.get(key)
            filled = repo.model_canal(s, row) if routes is None else None
        if routes is None:
            assert filled is not None
            routes = routes_from_dict(filled)
            self.cache.put(key, routes)
        canal = routes.pooled
        summary = model_summary(row, dim, lineage)
        data = row.canal  # as stored: each correction names its path's row
        pooled_data = data.get("pooled", data) if routes.n_routes > 1 else data
        sections = pooled_data.get("sections") if isinstance(pooled_data, dict) else None
        route_canals = None if routes.n_routes == 1 else [
            schemas.RouteCanal(route=k, n_demos=int(c.n_demos), directrix=_tolist(c.directrix),
                               radii=_tolist(c.radii)) for k, c in enumerate(routes.canals)]
        return schemas.ModelOut(
            **summary.model_dump(),
            directrix=_tolist(canal.directrix),
            arclength=_tolist(canal.arclength),
            radii=_tolist(canal.radii),
            frames=schemas.Frames(tangents=_tolist(canal.tangents), normals=_tolist(canal.normals),
                                  binormals=_tolist(canal.binormals)),
            bounds=_tolist(canal.bounds),
            sections=sections if isinstance(sections, dict) else None,
            serialized=data if serialized else None,
            route_canals=route_canals,
        )

    def mesh(self, name: str, version: int | None, n_angles: int, caps: bool,
             envelope: bool) -> canal_core.Mesh:
        """The canal's surface mesh from canal_core."""
        canal, _row, _version, _dim = self.load_canal(name, version)
        return canal.mesh(n_angles=n_angles, caps=caps, envelope=envelope)

    # ---- corrections ------------------------------------------------------------------------

    def correct(self, name: str, body: schemas.CorrectionIn, *, instance: str | None = None,
                time_unit: str | None = None) -> schemas.CorrectedModel:
        """Refine a model version by a person's correction (:meth:`ModelCorrections.correct`).
        Its timestamps (in ``time_unit``, seconds when None) are held to a demonstration's
        rules and stored as seconds."""
        if body.timestamps is None and time_unit is not None:
            raise InvalidInput(f"time_unit={time_unit} was given, but the correction has no "
                               "timestamps", field="time_unit")
        if body.timestamps is not None:
            # a correction's path is not fitted on its own: no shortest span, as from a file
            times = check_timestamps(body.timestamps, len(body.samples), time_unit, 0.0)
            body = body.model_copy(update={"timestamps": times.tolist()})
        return self.corrections.correct(name, body, instance=instance)

    def list_corrections(self, name: str, offset: int, limit: int
                         ) -> schemas.Page[schemas.CorrectionOut]:
        """A page of the skill's corrections, oldest first (those the latest version does
        not hold say they are undone)."""
        return self.corrections.list_corrections(name, offset, limit)

    def get_correction(self, name: str, correction_id: int) -> schemas.CorrectionPath:
        """One correction with its path (:meth:`ModelCorrections.get_correction`)."""
        return self.corrections.get_correction(name, correction_id)

    def undo_correction(self, name: str, correction_id: int) -> schemas.CorrectedModel:
        """A new latest version without one correction (:meth:`ModelCorrections.undo_correction`)."""
        return self.corrections.undo_correction(name, correction_id)

    # ---- reproductions ----------------------------------------------------------------------

    def reproduce(self, name: str, body: schemas.ReproductionRequest,
                  cancel: threading.Event | None = None
                  ) -> schemas.ReproductionOut | schemas.ReproductionBatchOut:
        """Reproduce from one start or a batch; every start is checked before any is computed.

        A request is stopped once it has run ``reproduce_max_seconds``
        (``CANAL_REPRODUCE_MAX_SECONDS``): before its next start, or inside a start's detour
        search; a batch also stops before its next start once ``cancel`` is set (its client
        left)."""
        began = time.monotonic()
        version = None if body.model == "latest" else int(body.model)
        routes, _row, ref = self._load_routes(name, version)
        canal = routes.pooled
        found_version, dim = ref.version, ref.dim
        forced = check_route(body.route, routes.n_routes, "route")
        if body.start is not None:
            starts, fields = [body.start], ["start"]
        else:
            assert body.starts is not None
            starts, fields = body.starts, [f"starts[{i}]" for i in range(len(body.starts))]
        inputs = check_reproduction_inputs(canal.directrix, canal.radii, starts, fields,
                                           body.goal, body.duration, body.start_orientation)
        notes = []
        if canal.section_times is None and body.duration is not None:
            # Without a duration the answer's null times say it all; with one, the pacing
            # is an assumption worth stating.
            notes.append("model has no time stamps: times follow the demonstrations' pace by their "
                         "sample index (a steady logger), scaled to the duration"
                         if canal.section_pace is not None else
                         "model has no time stamps: times follow arc length at constant speed")
        start_orientation = body.start_orientation
        if start_orientation is not None and not canal.has_orientation:
            notes.append("model has no orientation: start_orientation ignored")
            start_orientation = None
        scene_version, scene = self.scene_of(name, dim)
        if body.obstacles:
            sent_list = [o.as_dict() for o in body.obstacles]
            check_obstacles(sent_list)
            sent = canal_core.obstacles.scene_from_list(sent_list, dim)
            scene = sent if scene is None else canal_core.obstacles.merged_scene(scene, sent)
        results: list[canal_core.Reproduction] = []
        choices: list[RouteChoice] = []
        for start, field in zip(inputs.starts, fields, strict=True):
            if results:
                self._check_batch_time(began, len(results), len(fields), cancel)
            choice = (RouteChoice(forced, "forced") if forced is not None
                      else routes.choose(start))
            choices.append(choice)
            try:
                result = routes.canal_for(choice).reproduce_detailed(
                    start, outside=body.outside, goal=inputs.goal, duration=inputs.duration,
                    start_orientation=start_orientation, obstacles=scene,
                    persistence=body.persistence, deadline=began + self.reproduce_max_seconds)
            except canal_core.TooSlowError as exc:
                raise self._too_slow(f"a detour search still running at {field} after "
                                     f"{len(results)} of {len(fields)} starts: give fewer obstacles "
                                     "near the path, or fewer starts at once", field) from exc
            except canal_core.CanalError as exc:
                # canal_core names its own argument "start"; the client sent starts[i].
                at = field if exc.field in (None, "start") else exc.field
                raise CanalRejected(exc, exc.message, field=at) from exc
            used = ", ".join([field] + [k for k in ("goal", "duration", "start_orientation")
                                        if getattr(body, k) is not None])
            check_finite_answer({"positions": result.positions, "times": result.times,
                                 "velocities": result.velocities,
                                 "orientations": result.orientations, "eta": result.eta,
                                 "ratios": result.ratios}, used)
            results.append(result)
        self._keep_reproductions(name, ref, results)
        outs = []
        for result, choice in zip(results, choices, strict=True):
            self.metrics.reproductions.labels(str(bool(result.inside)).lower()).inc()
            # Built from values made here (floats, ints, bools, lists of them): validating
            # 6,000 floats again would cost more than the reproduction's math.
            outs.append(schemas.ReproductionOut.model_construct(
                positions=_tolist(result.positions), start=_tolist(result.start),
                inside=bool(result.inside), eta=float(result.eta),
                section_index=int(result.section_index), projected=bool(result.projected),
                model_version=found_version,
                times=_tolist(result.times), velocities=_tolist(result.velocities),
                orientations=_tolist(result.orientations), goal=_tolist(result.goal),
                blocked=None if result.blocked is None else schemas.BlockedOut.model_construct(
                    **result.blocked.to_dict()),
                scene_version=scene_version, obstacles=0 if scene is None else len(scene),
                start_clearance=result.start_clearance,
                notes=(notes + _orientation_notes(canal, result, start_orientation)
                       + _goal_notes(result, scene)),
                route=choice.route, route_reason=choice.reason, approach=int(result.approach),
                ratios=_tolist(result.ratios),
            ))
        if body.start is not None:
            return outs[0]
        return schemas.ReproductionBatchOut.model_construct(reproductions=outs)

    def _check_batch_time(self, began: float, done: int, total: int,
                          cancel: threading.Event | None) -> None:
        """Stop a batch whose client left, or that has used its server time."""
        if cancel is not None and cancel.is_set():
            self.metrics.reproductions_stopped.labels("client_left").inc()
            raise ReproductionCancelled("the client left: the batch of reproductions was stopped",
                                        field="starts")
        spent = time.monotonic() - began
        if spent > self.reproduce_max_seconds:
            raise self._too_slow(f"{done} of {total} starts done in {spent:.1f} s: send fewer "
                                 "starts at once (or fewer obstacles)", "starts")

    def _too_slow(self, got: str, field: str) -> ReproductionTooSlow:
        """The error of a request stopped at ``CANAL_REPRODUCE_MAX_SECONDS``, counted."""
        self.metrics.reproductions_stopped.labels("too_slow").inc()
        return ReproductionTooSlow(f"expected the reproductions within CANAL_REPRODUCE_MAX_SECONDS = "
                                   f"{self.reproduce_max_seconds:g} s of server time, got {got}",
                                   field=field)

    def _keep_reproductions(self, name: str, ref: repo.ModelRef,
                            results: list[canal_core.Reproduction]) -> None:
        """Store the reproductions for the recordings (every replica's recording draws them
        from the database) and tell the recorder."""
        if self.recorder is None:
            return
        if self.reproductions_kept <= 0:
            for result in results:
                self._record("reproduction", partial(_tell_reproduction, name, ref.version,
                                                     result))
            return
        try:
            kept = repo.insert_reproductions(self.db, ref.skill_id, ref.skill_created_at,
                                             ref.version, results, self.reproductions_kept)
        except Exception:
            # The answer is computed and right; only its place in the recordings is lost
            # (a busy or unreachable database), so the request does not fail for it.
            log.exception("could not keep %d reproduction(s) of %r for the recordings",
                          len(results), name)
            return
        instance = repo.skill_instance(ref.skill_id, ref.skill_created_at)
        for result, stored in zip(results, kept, strict=False):
            self._record("reproduction", partial(
                _tell_reproduction, name, ref.version, result, number=stored.number,
                t_ns=repo.created_ns(stored.created_at), instance=instance))

    # ---- scenes -----------------------------------------------------------------------------

    def get_scene(self, name: str) -> schemas.SceneOut:
        """The skill's scene (version 0 and no obstacles when it never had one)."""
        with self.db.read() as s:
            skill = repo.get_skill(s, name)
            row = repo.get_scene(s, skill)
            if row is None:
                return schemas.SceneOut(skill=name, version=0, obstacles=[])
            return schemas.SceneOut(skill=name, version=row.version, obstacles=row.obstacles,
                                    updated_at=row.updated_at)

    def put_scene(self, name: str, obstacles: Sequence[dict[str, Any]]) -> schemas.SceneOut:
        """Replace the skill's scene (checked against its dimension first: a malformed obstacle
        stores nothing); every listener (the live bridge) hears of the new version."""
        check_obstacles(obstacles)
        with self.db.write() as s:
            skill = repo.get_skill(s, name, lock=True)  # puts in turn: the last write wins
            scene = canal_core.obstacles.scene_from_list(list(obstacles), skill.dim)
            row = repo.put_scene(s, skill, scene.to_list())
            out = schemas.SceneOut(skill=name, version=row.version, obstacles=row.obstacles,
                                   updated_at=row.updated_at)
            instance = repo.skill_instance(skill.id, skill.created_at)
        self.scene_listeners.notify(name, out.version, scene)
        self._record("scene_changed", lambda r: r.scene_changed(name, out.version, out.obstacles,
                                                                scene.dim, instance=instance))
        return out

    def scene_of(self, name: str, dim: int) -> tuple[int | None, canal_core.obstacles.Scene | None]:
        """(version, scene) of the skill's stored scene; (None, None) when it has none."""
        with self.db.read() as s:
            skill = repo.get_skill(s, name)
            row = repo.get_scene(s, skill)
            if row is None:
                return None, None
            version, items = row.version, row.obstacles
        return version, canal_core.obstacles.scene_from_list(items, dim) if items else None

    # ---- recordings -------------------------------------------------------------------------

    @property
    def recordings_enabled(self) -> bool:
        """Whether this service records (``--no-recordings`` turns it off)."""
        return self.recorder is not None

    def _recorder(self) -> RecorderLike:
        if self.recorder is None:
            raise Disabled("recordings are disabled on this service", field="recordings")
        return self.recorder

    def export_recording(self, name: str, kind: RecordingKind,
                         profile: Literal["foxglove", "ros2"] = "foxglove") -> Path:
        """A snapshot file of the skill's recording (the caller deletes it after sending)."""
        recorder = self._recorder()
        self.skill_dim(name)  # SkillNotFound before any file is made
        if kind == "rrd":
            return recorder.export_rrd(name)
        return recorder.export_mcap(name, profile=profile)

    def recording_provenance(self) -> dict[str, str]:
        """Headers of an export: which parts every replica answers alike (drawn from the
        database) and which only this replica recorded (what its recorder heard)."""
        shared = "demonstrations, models" + (", reproductions" if self.reproductions_kept > 0
                                             else "")
        local = "live" if self.reproductions_kept > 0 else "live, reproductions"
        return {"Canal-Recording-Shared": shared, "Canal-Recording-Per-Replica": local,
                "Canal-Replica": REPLICA}

    def rebuild_recording(self, name: str) -> dict[str, Any]:
        """Regenerate the skill's recording from the database; counts of what was logged."""
        recorder = self._recorder()
        self.skill_dim(name)
        try:
            result = recorder.rebuild(name)
        except RuntimeError as exc:
            raise RecordingFailed(f"could not rebuild the recording of {name!r}: {exc}",
                                  field="recordings") from exc
        if result.get("gone"):
            raise SkillNotFound(f"skill {name!r} was deleted while its recording was being "
                                "rebuilt", field="name")
        return {"skill": name, **result}


def _tell_reproduction(skill: str, version: int, result: canal_core.Reproduction,
                       recorder: RecorderLike, *, number: int | None = None,
                       t_ns: int | None = None, instance: str | None = None) -> None:
    recorder.reproduction(skill, version, result, number=number, t_ns=t_ns, instance=instance)


def _orientation_notes(canal: canal_core.Canal, result: canal_core.Reproduction,
                       start_orientation: object) -> list[str]:
    """Say how the orientations were made when the request could not tell."""
    if not canal.has_orientation:
        return []
    if start_orientation is None:
        return ["no start_orientation: orientations are the canal's mean orientation"]
    ratio = result.orientation_eta
    if ratio is not None and ratio > 1.0:
        return [f"start_orientation is {ratio:.3g} times the demonstrations' largest angle from "
                "the mean at its section: its offset is carried as far as the demonstrations "
                "kept theirs, outside what was demonstrated"]
    return []


def _revision(ref: repo.ModelRef) -> Revision:
    return repo.created_ns(ref.skill_created_at), ref.version


def _goal_notes(result: canal_core.Reproduction,
                scene: canal_core.obstacles.Scene | None) -> list[str]:
    """Say so when the goal asked for lies in an obstacle: the path goes around it, so it
    does not end on the goal the answer echoes."""
    if result.goal is None or scene is None or not len(scene) or result.blocked is not None:
        return []
    free = float(canal_core.obstacles.free_distances(result.goal[None, :], scene)[0])
    if free >= 0.0:
        return []
    miss = float(np.linalg.norm(result.positions[-1] - result.goal))
    return [f"goal lies inside an obstacle or its clearance ({-free:.3g} deep): the path goes "
            f"around it and ends {miss:.3g} from the goal"]


_INDEXED_FIELD = re.compile(r"^(demos|timestamps)\[(\d+)\]")


def _fit_rejected(exc: canal_core.CanalError, demo_ids: Sequence[int]) -> CanalRejected:
    """canal_core's fit error, wrapped with the field the client knows.

    canal_core names a demonstration by its list index (``demos[2]``); the client knows the
    stored id. The set as a whole (no field, or ``demos``) is the skill's demonstrations.
    """
    field = "demonstrations" if exc.field in (None, "", "demos") else exc.field
    message = exc.message
    match = _INDEXED_FIELD.match(exc.field or "")
    if match and int(match.group(2)) < len(demo_ids):
        demo_id = demo_ids[int(match.group(2))]
        field, message = f"demonstrations[id={demo_id}]", f"demonstration {demo_id}: {message}"
    return CanalRejected(exc, message, field=field)


def _demo_arrays(row: Demonstration) -> tuple[arrays.FloatArray, arrays.FloatArray | None,
                                              arrays.FloatArray | None]:
    positions = arrays.unpack(row.positions, row.n_points, row.dim)
    times = None if row.timestamps is None else arrays.unpack(row.timestamps, row.n_points)
    quats = None if row.orientations is None else arrays.unpack(row.orientations, row.n_points, 4)
    return positions, times, quats


__all__: Sequence[str] = ["CanalService", "RecorderLike"]
