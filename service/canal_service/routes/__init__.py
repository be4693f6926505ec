"""HTTP routes, one module per resource. Routes validate and translate; nothing else."""

from fastapi import APIRouter

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

api_router = APIRouter()
api_router.include_router(skills.router)
api_router.include_router(demonstrations.router)
api_router.include_router(models.router)
api_router.include_router(corrections.router)
api_router.include_router(reproductions.router)
api_router.include_router(scenes.router)
api_router.include_router(recordings.router)

__all__ = ["api_router", "health"]
