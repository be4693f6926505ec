"""Every error class, from a real answer of a real service (or a closed port)."""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from canal_client import (
    ApiError,
    ArgumentError,
    AsyncCanalClient,
    BadRequestError,
    CanalClient,
    CanalClientError,
    ConflictError,
    ConnectionFailedError,
    InvalidInputError,
    NotFoundError,
    OutsideCanalError,
    PayloadTooLargeError,
    ServerError,
    UnauthorizedError,
    UnsupportedMediaTypeError,
)
from canal_client.errors import error_from_response
from canal_client.rest import _Request
from canal_live import LiveService, closed_port_url, demo_positions, other_web_app


def test_not_found_and_conflict(client: CanalClient, unique_name: Callable[[str], str]) -> None:
    with pytest.raises(NotFoundError) as info:
        client.get_skill("no-such-skill")
    e = info.value
    assert (e.status, e.type, e.field) == (404, "not_found", "name")
    assert "no-such-skill" in e.message and str(e) == f"{e.message} (field: name)"
    with pytest.raises(NotFoundError):
        client.add_demo("no-such-skill", demo_positions(0))

    name = unique_name("dup")
    client.create_skill(name)
    with pytest.raises(ConflictError) as dup:
        client.create_skill(name)
    assert dup.value.status == 409 and dup.value.type == "conflict" and name in str(dup.value)
    with pytest.raises(ConflictError):  # fit with no demonstrations
        client.fit(name)
    with pytest.raises(NotFoundError):
        client.get_demo(name, 12345)


def test_invalid_input_names_the_field(client: CanalClient,
                                       unique_name: Callable[[str], str]) -> None:
    name = unique_name("nan")
    client.create_skill(name)
    bad = demo_positions(0)
    bad[1, 0] = math.nan
    with pytest.raises(InvalidInputError) as info:
        client.add_demo(name, bad)
    e = info.value
    assert (e.status, e.type, e.field) == (422, "invalid_input", "positions[1][0]")
    assert "finite" in e.message and e.details
    assert str(e).endswith("(field: positions[1][0])")
    with pytest.raises(InvalidInputError) as dim:
        client.add_demo(name, demo_positions(0, dim=2))
    assert dim.value.field is not None
    assert client.get_skill(name).n_demonstrations == 0  # nothing stored


@pytest.mark.parametrize("bad", ["..", ".", "{name}/demonstrations/{demo}", "{name}/scene"])
def test_a_name_that_is_a_path_reaches_no_other_resource(
        client: CanalClient, unique_name: Callable[[str], str], bad: str) -> None:
    # The client sent ".." as it is (the URL normalised it away: a reproduction of skill ".."
    # went to POST /reproductions), and a name holding '/' reached, and deleted, another
    # skill's demonstration or scene.
    name = unique_name("path")
    client.create_skill(name)
    demo = client.add_demo(name, demo_positions(0)).id
    with pytest.raises(InvalidInputError) as info:
        client.delete_skill(bad.format(name=name, demo=demo))
    assert info.value.status == 422 and info.value.field in ("name", "path"), info.value
    with pytest.raises(InvalidInputError):
        client.reproduce(bad.format(name=name, demo=demo), [0.0, 0.0, 0.0])
    assert client.get_demo(name, demo).id == demo
    assert client.get_skill(name).n_demonstrations == 1


def test_an_empty_skill_name_is_refused_before_anything_is_sent(client: CanalClient) -> None:
    # An empty name made /skills/ or /skills//fit: a bare "HTTP 307" or "no route" answer
    # that did not say the name was missing.
    for call in (lambda: client.get_skill(""), lambda: client.delete_skill(""),
                 lambda: client.fit(""), lambda: client.add_demo("", demo_positions(0)),
                 lambda: client.reproduce("", [0.0, 0.0, 0.0])):
        with pytest.raises(ArgumentError) as info:
            call()
        assert info.value.argument == "skill" and "name" in info.value.expected, info.value


def test_outside_canal_raise(client: CanalClient, fitted: str) -> None:
    with pytest.raises(OutsideCanalError) as info:
        client.reproduce(fitted, [0.0, 5.0, 0.0], outside="raise")
    assert isinstance(info.value, InvalidInputError)
    assert info.value.status == 422 and info.value.type == "outside_canal"
    assert info.value.field == "start"


def test_bad_upload_and_media_type(client: CanalClient, unique_name: Callable[[str], str],
                                   tmp_path: Path) -> None:
    name = unique_name("bad")
    client.create_skill(name)
    garbage = tmp_path / "broken.npy"
    garbage.write_bytes(b"this is not numpy")
    with pytest.raises(BadRequestError) as info:
        client.upload_demo_file(name, garbage)
    assert info.value.status == 400 and info.value.type == "bad_upload"
    raw = _Request("POST", f"/skills/{name}/demonstrations", lambda r: r, body=b"x",
                   content_type="text/plain")
    with pytest.raises(UnsupportedMediaTypeError) as media:
        client._call(raw)
    assert media.value.status == 415 and media.value.field == "Content-Type"


def test_payload_too_large(tmp_path: Path) -> None:
    with LiveService(tmp_path / "data", max_body_bytes=4000) as live, \
            CanalClient(live.url) as c:
        c.create_skill("big")
        with pytest.raises(PayloadTooLargeError) as info:
            c.add_demo("big", demo_positions(0, n=300))
        assert info.value.status == 413 and info.value.type == "payload_too_large"
        assert c.get_skill("big").n_demonstrations == 0


def test_token(tmp_path: Path) -> None:
    with LiveService(tmp_path / "data", token="s3cret") as live:
        with CanalClient(live.url) as anonymous:
            assert anonymous.health().status == "ok"  # /healthz never needs the token
            with pytest.raises(UnauthorizedError) as info:
                anonymous.list_skills()
            assert info.value.status == 401 and info.value.field == "Authorization"
        with CanalClient(live.url, token="wrong") as wrong, pytest.raises(UnauthorizedError):
            wrong.create_skill("x")
        with CanalClient(live.url, token="s3cret") as good:
            assert good.create_skill("x").name == "x"
            assert [s.name for s in good.list_skills()] == ["x"]
        # A token no HTTP header can carry failed at the first request with httpx's
        # UnicodeEncodeError; it is an ArgumentError naming the character, not the token.
        for bad, fault in (("tokén", "'é' at character 4 of 5"), ("s3cret ", "a space at character 7 of 7")):
            for client in (CanalClient, AsyncCanalClient):
                with pytest.raises(ArgumentError) as refused:
                    client(live.url, token=bad)
                assert str(refused.value).startswith("token: expected visible ASCII")
                assert str(refused.value).endswith(f"got {fault}")


def test_recordings_off_is_not_found(tmp_path: Path) -> None:
    with LiveService(tmp_path / "data") as live, CanalClient(live.url) as c:
        c.create_skill("s")
        target = tmp_path / "s.rrd"
        with pytest.raises(NotFoundError) as info:
            c.download_recording("s", "rrd", target)
        assert info.value.type == "disabled"
        assert not target.exists() and list(tmp_path.glob("*.part")) == []


def test_an_answer_that_is_not_a_recording_is_refused_and_nothing_written(tmp_path: Path) -> None:
    # A URL pointing at another web app answers 200 with a page: saving it as the .rrd
    # would leave a file no viewer opens.
    with other_web_app() as url:
        for kind in ("rrd", "mcap"):
            target = tmp_path / f"s.{kind}"
            with CanalClient(url) as c, pytest.raises(CanalClientError) as info:
                c.download_recording("s", kind, target)
            message = str(info.value)
            assert "is not a Canal recording" in message and f".{kind}" in message
            assert "text/html" in message and "<html>" in message

            async def scenario(kind: str = kind, target: Path = target) -> None:
                async with AsyncCanalClient(url) as ac:
                    await ac.download_recording("s", kind, target)

            with pytest.raises(CanalClientError, match="is not a Canal recording"):
                asyncio.run(scenario())
            assert not target.exists()
        assert list(tmp_path.iterdir()) == []


def test_unreachable_server() -> None:
    url = closed_port_url()
    with CanalClient(url, timeout=5) as c, pytest.raises(ConnectionFailedError) as info:
        c.health()
    assert url in str(info.value) and info.value.url == url

    async def scenario() -> None:
        async with AsyncCanalClient(url, timeout=5) as ac:
            await ac.list_skills()

    with pytest.raises(ConnectionFailedError):
        asyncio.run(scenario())


def test_error_parsing_fallbacks() -> None:
    e = error_from_response(502, b"<html>Bad gateway</html>")
    assert isinstance(e, ServerError) and e.type == "http_502" and "Bad gateway" in str(e)
    e = error_from_response(418, '{"detail": "teapot"}')
    assert type(e) is ApiError and str(e) == "teapot" and e.field is None
    e = error_from_response(422, '{"error": {"type": "degenerate_canal", "field": null, '
                                 '"message": "flat"}}')
    assert isinstance(e, InvalidInputError) and e.type == "degenerate_canal" and str(e) == "flat"


def test_numpy_arguments_are_checked_locally(client: CanalClient) -> None:
    with pytest.raises(ValueError, match="positions"):
        client.add_demo("anything", np.zeros(5))
    with pytest.raises(ValueError, match="start"):
        client.reproduce("anything", np.zeros((2, 3)))


@pytest.mark.parametrize(("call", "words"), [
    (lambda c: c.reproduce("s", "0,0,0"), ["start", "numbers", "'0,0,0'"]),
    (lambda c: c.reproduce("s", [0, "a", 0]), ["start", "numbers", "'a'"]),
    (lambda c: c.reproduce("s", {"x": 1}), ["start", "numbers", "dict"]),
    (lambda c: c.reproduce("s", [0, 0, 0], goal="1 2 3"), ["goal", "numbers", "'1 2 3'"]),
    (lambda c: c.reproduce_many("s", [[0, 0, 0], [1, 1]]), ["starts", "numbers"]),
    (lambda c: c.add_demo("s", [[0, 0, "x"]]), ["positions", "numbers", "'x'"]),
    (lambda c: c.add_demo("s", np.zeros((3, 3)), timestamps="fast"), ["timestamps", "'fast'"]),
    (lambda c: c.correct("s", "all of them"), ["samples", "numbers", "'all of them'"]),
    (lambda c: c.reproduce("s", [0, 0, 0], duration="2 s"), ["duration", "a number", "'2 s'"]),
    (lambda c: c.reproduce("s", [0, 0, 0], model="v2"), ["model", "version number", "'v2'"]),
    (lambda c: c.download_recording("s", "zip", "/tmp/x"), ["kind", "'rrd' or 'mcap'", "'zip'"]),
    # numpy cast complex numbers to real, dropping the imaginary parts with a warning only
    (lambda c: c.add_demo("s", np.ones((5, 3)) * (1 + 2j)), ["positions", "real numbers", "complex"]),
    (lambda c: c.reproduce("s", np.array([0, 1j, 0])), ["start", "real numbers", "complex"]),
    # a lone obstacle where a list of them goes: Python's "dictionary update sequence" error
    (lambda c: c.set_scene("s", {"kind": "sphere", "center": [0, 0, 0], "radius": 0.1}),
     ["obstacles", "a list of obstacles", "dict"]),
    (lambda c: c.set_scene("s", ["sphere"]), ["obstacles[0]", "an obstacle", "'sphere'"]),
    (lambda c: c.reproduce("s", [0, 0, 0], obstacles=[1.5]), ["obstacles[0]", "an obstacle", "1.5"]),
])
def test_arguments_that_are_not_numbers_name_themselves(client: CanalClient, call: Callable[[CanalClient], Any],
                                                        words: list[str]) -> None:
    """An argument refused before anything is sent is a CanalClientError (and a ValueError)
    naming the argument, what it expected and what came, not numpy's conversion message."""
    with pytest.raises(CanalClientError) as info:
        call(client)
    assert isinstance(info.value, ValueError)
    message = str(info.value)
    assert all(w in message for w in words), message
    assert "could not convert" not in message and "float() argument" not in message


def test_error_bodies_are_read_as_the_protocols_error_response() -> None:
    """The protocol's ErrorResponse shape (``field`` optional) gives the typed error; any
    other body becomes the message of the status's class."""
    outside = error_from_response(422, b'{"error": {"type": "outside_canal", "message": "m"}}')
    assert isinstance(outside, OutsideCanalError) and (outside.message, outside.field) == ("m", None)
    bad = error_from_response(422, b'{"error": {"type": "invalid_input", "field": "positions[3]",'
                                   b' "message": "bad", "details": [{"loc": "x"}]}}')
    assert (bad.type, bad.field, bad.details) == ("invalid_input", "positions[3]", [{"loc": "x"}])
    assert str(bad) == "bad (field: positions[3])"
    plain = error_from_response(404, b'{"detail": "Not Found"}')
    assert isinstance(plain, NotFoundError) and (plain.type, plain.message) == ("http_404",
                                                                                "Not Found")
    html = error_from_response(502, b"<html>bad gateway</html>")
    assert isinstance(html, ServerError) and html.message == "<html>bad gateway</html>"


def test_live_and_simulation_refusals_are_client_errors() -> None:
    """One base class for everything the client raises on purpose: the live streamer's and the
    simulated robot's refusals too, each naming the argument before any session opens."""
    from canal_client.live import LiveError, PoseStreamer
    from canal_client.sim import SimInputError, run_sim

    assert issubclass(LiveError, CanalClientError) and issubclass(SimInputError, CanalClientError)
    with pytest.raises(ArgumentError, match=r"^encoding: expected 'binary' or 'json', got 'xml'$"):
        PoseStreamer("s", "r", encoding="xml")
    with pytest.raises(SimInputError, match=r"expected lag 'first-order' or 'pd', got 'pid'") as info:
        run_sim("s", lag="pid")  # type: ignore[arg-type]
    assert info.value.param == "lag"
