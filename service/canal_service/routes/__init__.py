"""HTTP routes, one module per resource. Routes validate and translate; nothing else."""

from fastapi import APIRouter, Depends

from ..deps import known_query
from . import (
    corrections,
    demonstrations,
    health,
    models,
    recordings,
    reproductions,
    scenes,
    skills,
)

# The API refuses a query parameter a route does not take; the pages a browser opens (the
# viewer reads its own ?url=) and the health probes do not.
api_router = APIRouter(dependencies=[Depends(known_query)])
api_router.include_router(skills.router)
api_router.include_router(demonstrations.router)
api_router.include_router(models.router)
api_router.include_router(corrections.router)
api_router.include_router(reproductions.router)
api_router.include_router(scenes.router)
api_router.include_router(recordings.router)

__all__ = ["api_router", "health"]
