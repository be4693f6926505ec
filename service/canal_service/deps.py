"""Typed dependencies shared by the routes.

The getters are ``async def`` on purpose: FastAPI runs a plain ``def`` dependency in the
thread pool, one round trip through a worker thread (and the GIL hand-overs it costs) per
request, to read an attribute.
"""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import Depends, Path, Query, Request

from canal_protocol.schemas import MAX_ID, SKILL_NAME_PATTERN

from .core.config import Settings
from .errors import InvalidInput
from .health import ServiceHealth
from .service import CanalService


async def get_service(request: Request) -> CanalService:
    """The app's service object (built by ``create_app``)."""
    service: CanalService = request.app.state.service
    return service


async def get_health(request: Request) -> ServiceHealth:
    """The app's health check (built by ``create_app``)."""
    health: ServiceHealth = request.app.state.health
    return health


async def get_settings(request: Request) -> Settings:
    """The settings the app was built with."""
    settings: Settings = request.app.state.settings
    return settings


def _query_names(dependant: Any) -> frozenset[str]:
    """The query parameters a route takes, its dependencies' included."""
    names = {p.alias for p in dependant.query_params}
    for sub in dependant.dependencies:
        names |= _query_names(sub)
    return frozenset(names)


#: (method, path template) -> the query parameters the route takes
_TAKEN: dict[tuple[str, str], frozenset[str]] = {}


async def known_query(request: Request) -> None:
    """Refuse a query parameter the route does not take, as a body's unknown field is: a
    misspelt ``?wieght=2`` would otherwise leave the default in its place without a word."""
    if not request.query_params:
        return
    route = request.scope.get("route")
    dependant = getattr(route, "dependant", None)
    if dependant is None:
        return
    key = (request.method, str(getattr(route, "path", "")))
    taken = _TAKEN.get(key)
    if taken is None:
        taken = _TAKEN[key] = _query_names(dependant)
    for name in request.query_params:
        if name not in taken:
            expected = ", ".join(sorted(taken)) if taken else "none"
            raise InvalidInput(f"expected only the query parameters this route takes ({expected}), "
                               f"got {name!r}", field=name)


ServiceDep = Annotated[CanalService, Depends(get_service)]
HealthDep = Annotated[ServiceHealth, Depends(get_health)]
SettingsDep = Annotated[Settings, Depends(get_settings)]
SkillName = Annotated[
    str, Path(pattern=SKILL_NAME_PATTERN, description="Skill name", examples=["pour"])
]
#: The path parameter is ``{id}`` (docs/rest.md), the name its refusals and 404s give.
DemoId = Annotated[int, Path(ge=1, le=MAX_ID, alias="id", description="Demonstration id")]
Offset = Annotated[int, Query(ge=0, le=MAX_ID, description="Items to skip")]
Limit = Annotated[int, Query(ge=1, le=1000, description="Page size")]


def parse_version(value: str, field: str = "version") -> int | None:
    """'latest' -> None, a positive number -> int; anything else is InvalidInput naming ``field``."""
    if value == "latest":
        return None
    if value.isascii() and value.isdigit() and 1 <= int(value) <= MAX_ID:
        return int(value)
    raise InvalidInput(f"expected a model version number or 'latest', got {value!r}", field=field)


VersionRef = Annotated[
    str, Path(description="A version number or 'latest'", examples=["latest", "1"],
              pattern=r"^(latest|[0-9]{1,10})$")
]
