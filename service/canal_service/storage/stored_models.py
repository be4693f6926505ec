"""A model version's canal as stored: each correction's path named by its correction's id.

A refined model's dict (``canal_core``'s ``canal-model`` or ``canal-routes``) carries every
correction applied since the fit, path and all. Stored that way, each version would repeat
every earlier correction's path, and K corrections of M samples would cost K^2 M. The path
(``samples``, ``timestamps``, ``orientations``, ``plan``) is stored once, in the correction's
row; a version's dict keeps the rest of each correction (its span, cuts and the rows of the
canal before it) with ``correction_id`` and an empty path. That dict is still a model
``canal_core.Canal.from_dict`` reads (a correction with no samples); the service fills the
paths back in from the correction rows before it decodes one (:func:`with_paths`).

A dict stored with its paths inside (written before paths were stored once) has no
``correction_id`` and is read as it is.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Iterator, Mapping
from typing import Any

import numpy as np

from . import arrays
from .models import Correction

#: The keys of a correction's path in the model dict; its row holds them.
PATH_KEYS = ("samples", "timestamps", "orientations", "plan")


def _canals(model: dict[str, Any]) -> Iterator[dict[str, Any]]:
    """Every canal dict of a stored model: the canal, or each route's and the canal of all."""
    if model.get("format") == "canal-routes":
        yield from model.get("routes") or ()
        if isinstance(model.get("pooled"), dict):
            yield model["pooled"]
    else:
        yield model


def _each_canal(model: dict[str, Any],
                change: Callable[[dict[str, Any]], dict[str, Any]]) -> dict[str, Any]:
    """A copy of ``model`` with ``change`` made to each of its canal dicts (:func:`_canals`)."""
    if model.get("format") == "canal-routes":
        return {**model, "routes": [change(c) for c in model.get("routes") or ()],
                "pooled": change(model["pooled"])}
    return change(model)


def _key(packed: tuple[bytes | None, ...]) -> bytes:
    """A digest of a path's four packed arrays (None: absent)."""
    h = hashlib.sha256()
    for blob in packed:
        h.update(b"-" if blob is None else len(blob).to_bytes(8, "little") + blob)
    return h.digest()


def _row_key(row: Correction) -> bytes:
    return _key((row.samples, row.timestamps, row.orientations, row.plan))


def _entry_key(entry: Mapping[str, Any]) -> bytes:
    return _key(tuple(None if entry.get(k) is None else
                      arrays.pack(np.asarray(entry[k], dtype=np.float64)) for k in PATH_KEYS))


def without_paths(model: dict[str, Any], rows: list[Correction]) -> dict[str, Any]:
    """``model`` with each correction's path left out and its row's id named instead.

    ``rows``: the corrections the version holds. A correction is matched to its row by its
    path's bytes (rows with one path are interchangeable: each gives the same path back); one
    matching no row keeps its path.
    """
    ids = {_row_key(r): int(r.id) for r in rows}

    def stripped(canal: dict[str, Any]) -> dict[str, Any]:
        corrections = []
        for entry in canal.get("corrections") or ():
            found = ids.get(_entry_key(entry)) if "correction_id" not in entry else None
            if found is None:
                corrections.append(entry)
                continue
            corrections.append({**entry, "samples": [], "timestamps": None,
                                "orientations": None, "plan": None, "correction_id": found})
        return {**canal, "corrections": corrections}

    return _each_canal(model, stripped)


def path_ids(model: dict[str, Any]) -> list[int]:
    """The ids of the corrections whose paths ``model`` names, each once."""
    found: dict[int, None] = {}
    for canal in _canals(model):
        for entry in canal.get("corrections") or ():
            if entry.get("correction_id") is not None:
                found[int(entry["correction_id"])] = None
    return list(found)


def path_of(row: Correction) -> dict[str, Any]:
    """A correction row's path as the model dict holds it."""
    dim = row.dim
    return {
        "samples": arrays.unpack(row.samples, row.n_points, dim).tolist(),
        "timestamps": None if row.timestamps is None else
        arrays.unpack(row.timestamps, row.n_points).tolist(),
        "orientations": None if row.orientations is None else
        arrays.unpack(row.orientations, row.n_points, 4).tolist(),
        "plan": None if row.plan is None else
        arrays.unpack(row.plan, len(row.plan) // (8 * dim), dim).tolist(),
    }


def with_paths(model: dict[str, Any], paths: Mapping[int, dict[str, Any]]) -> dict[str, Any]:
    """``model`` with each named correction's path filled back in (``paths``: by id, as
    :func:`path_of` gives them); ``model`` itself is left as it is."""
    if not paths:
        return model

    def filled(canal: dict[str, Any]) -> dict[str, Any]:
        corrections = [
            {**entry, **paths[int(entry["correction_id"])]}
            if entry.get("correction_id") is not None and int(entry["correction_id"]) in paths
            else entry
            for entry in canal.get("corrections") or ()
        ]
        return {**canal, "corrections": corrections}

    return _each_canal(model, filled)


__all__ = ["PATH_KEYS", "path_ids", "path_of", "with_paths", "without_paths"]
