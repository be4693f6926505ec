"""The fit options of the HTTP contract are canal_core's: same names, defaults and limits.

A request the protocol accepts is one ``canal_core.fit_options`` accepts, and the other way
round, at every bound; a name or default added to canal_core shows up here without an edit.
"""

from __future__ import annotations

import dataclasses
from typing import Any, get_args

import pytest
from pydantic import ValidationError

from canal_core import options as core
from canal_core.errors import InvalidInputError
from canal_protocol import options
from canal_protocol.schemas import FitRequest

CORE_OPTIONS = {f.name for f in dataclasses.fields(core.FitOptions)}
# What the service does around the fit (routes: canal_core.routes around canal_core.fit),
# not how canal_core fits one canal.
SERVICE_ONLY = {"by_time", "demo_ids", "orientation", "keep_corrections", "routes", "route_separation"}


def test_every_core_option_is_a_request_field_with_the_core_default() -> None:
    assert set(FitRequest.model_fields) == CORE_OPTIONS | SERVICE_ONLY
    request, defaults = FitRequest(), core.FitOptions()
    for name in CORE_OPTIONS:
        assert getattr(request, name) == getattr(defaults, name), name


def test_the_names_offered_are_the_core_names() -> None:
    schema = FitRequest.model_json_schema()["properties"]
    assert tuple(schema["cross_section"]["enum"]) == core.CROSS_SECTIONS
    assert tuple(schema["frames"]["enum"]) == core.FRAMES == get_args(core.FrameKind)
    assert tuple(schema["alignment"]["enum"]) == core.ALIGNMENTS
    assert tuple(schema["directrix"]["enum"]) == core.DIRECTRICES


def accepted_by_protocol(**fields: Any) -> bool:
    try:
        FitRequest(**fields)
    except ValidationError:
        return False
    return True


def accepted_by_core(**fields: Any) -> bool:
    try:
        core.fit_options(**fields)
    except InvalidInputError:
        return False
    return True


@pytest.mark.parametrize("fields", [
    {"n_samples": options.MIN_SAMPLES}, {"n_samples": options.MIN_SAMPLES - 1},
    {"n_samples": options.MAX_SAMPLES}, {"n_samples": options.MAX_SAMPLES + 1},
    {"frame_smoothing": 0.0}, {"frame_smoothing": -1e-9},
    {"frame_smoothing": options.MAX_FRAME_SMOOTHING},
    {"frame_smoothing": options.MAX_FRAME_SMOOTHING + 1e-9},
    *({"cross_section": kind} for kind in (*core.CROSS_SECTIONS, "interval", "square")),
    *({"frames": kind} for kind in (*core.FRAMES, "serret")),
    *({"alignment": kind} for kind in (*core.ALIGNMENTS, "linear")),
    *({"directrix": kind} for kind in (*core.DIRECTRICES, "median")),
])
def test_protocol_and_core_agree_at_every_bound(fields: dict[str, Any]) -> None:
    assert accepted_by_protocol(**fields) == accepted_by_core(**fields), fields


def test_one_limit_for_n_samples() -> None:
    assert options.MAX_SAMPLES == core.MAX_SAMPLES
    field = FitRequest.model_json_schema()["properties"]["n_samples"]
    assert (field["minimum"], field["maximum"]) == (core.MIN_SAMPLES, core.MAX_SAMPLES)


def test_a_request_passes_to_the_core_as_it_is() -> None:
    request = FitRequest(cross_section="ellipse", frames="frenet", n_samples=77,
                         frame_smoothing=0.1, alignment="dtw", directrix="gmr")
    fitted = core.fit_options(**request.model_dump(include=CORE_OPTIONS))
    assert dataclasses.asdict(fitted) == request.model_dump(include=CORE_OPTIONS)


def test_the_time_units_a_route_takes_are_the_ones_converted() -> None:
    # the route's query parameter is typed by TimeUnit, the conversion reads TIME_UNITS
    assert set(get_args(options.TimeUnit)) == set(options.TIME_UNITS)
