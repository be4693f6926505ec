"""Python client of the Canal service.

- :class:`CanalClient` / :class:`AsyncCanalClient`: typed REST clients (httpx), numpy in and out;
  they return the contract's models (:mod:`canal_protocol.schemas`; the resources with arrays
  as numpy subclasses, :mod:`canal_client.resources`);
- :mod:`canal_client.errors`: the errors they raise, carrying the service's message;
- ``canal``: the command line (:mod:`canal_client.cli`);
- ``PoseStreamer`` (:mod:`canal_client.live`) and ``run_sim``/``SimResult``
  (:mod:`canal_client.sim`): the robot side over Zenoh;
The live wire codecs are in :mod:`canal_protocol.wire` (shared with the service).
The clients are imported on first use, so ``import canal_client`` stays light.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from .errors import (
    ApiError,
    ArgumentError,
    BadRequestError,
    CanalClientError,
    ConflictError,
    ConnectionFailedError,
    DegenerateCanalError,
    InvalidInputError,
    NotFoundError,
    OutsideCanalError,
    PayloadTooLargeError,
    RequestTimeoutError,
    ServerError,
    UnauthorizedError,
    UnsupportedMediaTypeError,
)
from .resources import (
    DemoCreated,
    Demonstration,
    DemoSummary,
    Health,
    Model,
    ModelFrames,
    ModelSummary,
    Reproduction,
    ReproductionBatch,
    Skill,
)

if TYPE_CHECKING:
    from .live import LiveError, PoseStreamer
    from .rest import DEFAULT_URL, AsyncCanalClient, CanalClient
    from .sim import SimResult, run_sim

__all__ = [
    "DEFAULT_URL",
    "ApiError",
    "ArgumentError",
    "AsyncCanalClient",
    "BadRequestError",
    "CanalClient",
    "CanalClientError",
    "ConflictError",
    "ConnectionFailedError",
    "DegenerateCanalError",
    "DemoCreated",
    "DemoSummary",
    "Demonstration",
    "Health",
    "InvalidInputError",
    "LiveError",
    "Model",
    "ModelFrames",
    "ModelSummary",
    "NotFoundError",
    "OutsideCanalError",
    "PayloadTooLargeError",
    "PoseStreamer",
    "Reproduction",
    "ReproductionBatch",
    "RequestTimeoutError",
    "ServerError",
    "SimResult",
    "Skill",
    "UnauthorizedError",
    "UnsupportedMediaTypeError",
    "run_sim",
]

# name -> module; loaded on first attribute access (PEP 562), so that a robot importing only
# the errors pulls in neither httpx nor zenoh.
_LAZY = {
    "DEFAULT_URL": ".rest",
    "AsyncCanalClient": ".rest",
    "CanalClient": ".rest",
    "LiveError": ".live",
    "PoseStreamer": ".live",
    "SimResult": ".sim",
    "run_sim": ".sim",
}


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module, __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
