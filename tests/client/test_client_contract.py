"""The client's contract against the live service's OpenAPI document, and the two clients
built from one description.

``canal_client.rest.ENDPOINTS`` names every exchange the client has (method, path, the model
it sends, the model it reads the answer as, query parameters). Each one must exist in the
real service's ``/openapi.json`` (uvicorn on 127.0.0.1) with the same fields and types: a
route renamed or moved, a field added, dropped or retyped on either side fails here.
"""

from __future__ import annotations

import inspect
import re
from collections.abc import Callable
from typing import Any

import canal_client.rest as rest
import httpx
import pytest
from canal_client import AsyncCanalClient, CanalClient
from canal_live import LiveService
from pydantic import BaseModel

from canal_protocol.schemas import FitRequest

# What a schema says about the data (not its titles, prose or examples).
_PROSE = {"title", "description", "examples"}


def normalized(schema: Any, resolve: Callable[[str], Any]) -> Any:
    """``schema`` with every ``$ref`` inlined and the prose left out."""
    if isinstance(schema, list):
        return [normalized(s, resolve) for s in schema]
    if not isinstance(schema, dict):
        return schema
    if "$ref" in schema:
        return normalized(resolve(schema["$ref"]), resolve)
    # FastAPI's document leaves out every null (``"default": null`` among them).
    return {k: (v if k in ("default", "enum", "const", "required") else normalized(v, resolve))
            for k, v in schema.items() if k not in _PROSE and v is not None}


def without_null(schema: Any) -> Any:
    """An optional body (``anyOf [X, null]``) is X."""
    branches = schema.get("anyOf") if isinstance(schema, dict) else None
    if branches and {"type": "null"} in branches and len(branches) == 2:
        return next(b for b in branches if b != {"type": "null"})
    return schema


def client_schema(model: type[BaseModel], mode: Any) -> Any:
    doc = model.model_json_schema(mode=mode)
    defs = doc.pop("$defs", {})
    return normalized(doc, lambda ref: defs[ref.rsplit("/", 1)[1]])


@pytest.fixture(scope="module")
def openapi(service: LiveService) -> dict[str, Any]:
    resp = httpx.get(f"{service.url}/openapi.json", timeout=30.0)
    assert resp.status_code == 200
    doc: dict[str, Any] = resp.json()
    return doc


def service_schema(openapi: dict[str, Any], schema: Any) -> Any:
    components = openapi["components"]["schemas"]
    return normalized(without_null(schema),
                      lambda ref: components[ref.rsplit("/", 1)[1]])


def operation(openapi: dict[str, Any], endpoint: rest.Endpoint) -> dict[str, Any]:
    assert endpoint.path in openapi["paths"], f"the service has no path {endpoint.path}"
    ops = openapi["paths"][endpoint.path]
    assert endpoint.method.lower() in ops, f"the service has no {endpoint.method} {endpoint.path}"
    op: dict[str, Any] = ops[endpoint.method.lower()]
    return op


@pytest.mark.parametrize("name", sorted(rest.ENDPOINTS))
def test_every_endpoint_matches_the_live_openapi(openapi: dict[str, Any], name: str) -> None:
    endpoint = rest.ENDPOINTS[name]
    op = operation(openapi, endpoint)

    params = {p["name"]: p["in"] for p in op.get("parameters", [])}
    assert {n for n, where in params.items() if where == "path"} == set(
        re.findall(r"{(\w+)}", endpoint.path))
    missing = set(endpoint.query) - {n for n, where in params.items() if where == "query"}
    assert not missing, f"{name}: the service takes no query parameter {sorted(missing)}"

    content = op.get("requestBody", {}).get("content", {})
    if endpoint.request is not None:
        assert "application/json" in content, f"{name}: the service takes no JSON body"
        assert client_schema(endpoint.request, "validation") == service_schema(
            openapi, content["application/json"]["schema"]), f"{name}: request fields differ"
    if endpoint.media_type is not None:
        assert endpoint.media_type in content

    responses = op["responses"]
    assert str(endpoint.status) in responses, f"{name}: the service never answers {endpoint.status}"
    if endpoint.response is not None:
        answer = responses[str(endpoint.status)]["content"]["application/json"]["schema"]
        theirs = service_schema(openapi, answer)
        # One route may answer one of several models (a reproduction or a batch of them).
        options = theirs["anyOf"] if "anyOf" in theirs else [theirs]
        assert client_schema(endpoint.response, "serialization") in options, (
            f"{name}: the client reads {endpoint.response.__name__}, whose fields differ from "
            f"what the service sends")


def test_the_diff_sees_a_dropped_field(openapi: dict[str, Any]) -> None:
    """The comparison is not vacuous: the client's Health of last session (no ``bridge``)
    differs from what the service sends."""

    class OldHealth(BaseModel):
        status: str
        database: str
        recorder: dict[str, Any]
        version: str

    answer = operation(openapi, rest.HEALTH)["responses"]["200"]["content"]
    theirs = service_schema(openapi, answer["application/json"]["schema"])
    assert client_schema(rest.HEALTH.response or OldHealth, "serialization") == theirs
    assert client_schema(OldHealth, "serialization") != theirs


def test_health_carries_the_bridge(client: CanalClient) -> None:
    health = client.health()
    assert health.status == "ok" and health.bridge["status"] in ("ok", "down", "disabled")
    assert health.model_dump(mode="json").keys() >= {"database", "recorder", "bridge", "version"}


def test_fit_offers_every_fit_option() -> None:
    """Every FitRequest field is a keyword of ``fit`` (none invented, none missing)."""
    keywords = set(inspect.signature(CanalClient(rest.DEFAULT_URL).fit).parameters) - {"skill"}
    assert keywords == set(FitRequest.model_fields)


def test_sync_and_async_clients_have_the_same_methods() -> None:
    sync, asynchronous = CanalClient(rest.DEFAULT_URL), AsyncCanalClient(rest.DEFAULT_URL)
    names = [n for n in dir(rest._Operations) if not n.startswith("_")]
    assert len(names) >= 19
    for name in names:
        s, a = getattr(sync, name), getattr(asynchronous, name)
        assert not inspect.iscoroutinefunction(s) and inspect.iscoroutinefunction(a), name
        assert inspect.signature(s) == inspect.signature(a), name
        assert s.__doc__ and s.__doc__ == a.__doc__, name
        assert s.__name__ == name and a.__qualname__ == f"AsyncCanalClient.{name}"
    sync.close()
