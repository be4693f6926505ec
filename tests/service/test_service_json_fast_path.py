"""The JSON upload fast path (orjson + numpy) accepts only what the strict model accepts, with
the same values; everything else falls back to the model and its errors."""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from canal_protocol.schemas import DemonstrationIn, _fast_demonstration, demonstration_from_json

scalars = st.one_of(
    st.floats(allow_nan=False, allow_infinity=False),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.booleans(), st.none(), st.sampled_from(["1", "true", "", "null"]),
)
numbers = st.one_of(st.floats(allow_nan=False, allow_infinity=False),
                    st.integers(min_value=-(2**60), max_value=2**60))
rows = st.lists(st.one_of(numbers, scalars), min_size=0, max_size=4)
labels = st.one_of(st.none(), st.text(max_size=20),
                   st.sampled_from(["true", "null false", 'say "hi"', "a\\nb", "x" * 300]))


def _slow(raw: bytes) -> DemonstrationIn | None:
    try:
        return DemonstrationIn.model_validate_json(raw)
    except ValidationError:
        return None


def _same(fast: DemonstrationIn, slow: DemonstrationIn) -> None:
    for key in ("positions", "timestamps", "orientations"):
        a, b = getattr(fast, key), getattr(slow, key)
        assert (a is None) == (b is None), key
        if a is not None:
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b, dtype=np.float64))
    assert fast.label == slow.label


@settings(max_examples=300, deadline=None)
@given(positions=st.lists(rows, min_size=0, max_size=6), label=labels,
       timestamps=st.one_of(st.none(), st.lists(st.one_of(numbers, scalars), max_size=6)),
       extra=st.sampled_from([{}, {"orientations": None}, {"labl": 1}, {"timestamps": True}]))
def test_fast_path_never_accepts_more_than_the_model(
    positions: list[Any], label: str | None, timestamps: list[Any] | None, extra: dict[str, Any]
) -> None:
    body: dict[str, Any] = {"positions": positions, "label": label, **extra}
    if timestamps is not None:
        body.setdefault("timestamps", timestamps)
    raw = json.dumps(body).encode()
    fast = _fast_demonstration(raw)
    slow = _slow(raw)
    if fast is not None:
        assert slow is not None, raw
        _same(fast, slow)


@pytest.mark.parametrize("raw", [
    b'{"positions": [[0, 0, 0], [1, 2.5, -3e-7], [2, 0, 1e308], [3, 0, -0.0]]}',
    b'{"label": "true", "positions": [[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]]}',
    b'{"positions": [[0, 0], [1, 0], [2, 1], [3, 0]], "timestamps": [0, 0.1, 0.2, 0.3],'
    b' "label": null, "orientations": null}',
    b'{"positions": [[0,0,0],[1,0,0],[2,0,0],[3,0,0]], "orientations": [[0,0,0,1],[0,0,0,1],'
    b'[0,0,0,1],[0,0,0,1]]}',
])
def test_common_bodies_take_the_fast_path_with_the_models_values(raw: bytes) -> None:
    fast = _fast_demonstration(raw)
    assert fast is not None
    assert isinstance(fast.positions, np.ndarray) and fast.positions.dtype == np.float64
    slow = _slow(raw)
    assert slow is not None
    _same(fast, slow)


@pytest.mark.parametrize("raw", [
    b'{"positions": [[0, 0, true], [1, 0, 0], [2, 0, 0], [3, 0, 0]], "label": "true"}',
    b'{"positions": [[0, 0, "1"], [1, 0, 0], [2, 0, 0], [3, 0, 0]]}',
    b'{"positions": [[0, 0, null], [1, 0, 0], [2, 0, 0], [3, 0, 0]], "label": null}',
    b'{"positions": [[0, 0, 0], [1, 0, 0], [2, 0], [3, 0, 0]]}',
    b'{"positions": [[0, 0, 0, 0], [1, 0, 0, 0], [2, 0, 0, 0], [3, 0, 0, 0]]}',
    b'{"position": [[0, 0, 0]]}',
    b'{"positions": [[0, 0, 0]], "label": "\\u0074rue"}',
    # what the one-pass byte check and the flat row conversion must not let through
    b'{"positions": [[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, [0]]]}',
    b'{"positions": [[0, 0, 0], [1, 0, 0], [2, 0, 0], 3]}',
    b'{"positions": [0, 1, 2, 3]}',
    b'{"positions": [[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, {"a": 1}]]}',
    b'{"positions": [[0,0,0],[1,0,0],[2,0,0],[3,0,0]], "positions": [[0,0,0],[1,0,0]]}',
    b'{"positions": [[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]], "timestamps": [0, [1], 2, 3]}',
    b'{"label": "1,2", "positions": [[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, "e"]]}',
])
def test_anything_else_goes_to_the_model(raw: bytes) -> None:
    assert _fast_demonstration(raw) is None
    if _slow(raw) is None:
        with pytest.raises(ValidationError):
            demonstration_from_json(raw)
    else:
        assert demonstration_from_json(raw).model_dump() == _slow(raw).model_dump()  # type: ignore[union-attr]
