"""/skills/{name}/scene: the obstacles every reproduction and live stream of a skill goes around."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Response, status

from canal_protocol.schemas import ErrorResponse, SceneIn, SceneOut

from ..deps import ServiceDep, SkillName

router = APIRouter(prefix="/skills/{name}", tags=["scenes"])
_ERRORS: dict[int | str, dict[str, Any]] = {
    code: {"model": ErrorResponse} for code in (404, 422)
}


@router.get("/scene", response_model=SceneOut, responses=_ERRORS)
def get_scene(name: SkillName, service: ServiceDep) -> SceneOut:
    """The skill's scene; version 0 with no obstacles when none was set."""
    return service.get_scene(name)


@router.put("/scene", response_model=SceneOut, responses=_ERRORS)
def put_scene(name: SkillName, body: SceneIn, service: ServiceDep) -> SceneOut:
    """Replace the skill's scene (the last write wins; ``version`` goes up by one).

    Every later reproduction, and every live stream from its next pose, goes around it. An
    obstacle that does not fit the skill's dimension is refused with 422 naming it, and
    nothing is stored.
    """
    return service.put_scene(name, [o.as_dict() for o in body.obstacles])


@router.delete("/scene", status_code=status.HTTP_204_NO_CONTENT, response_class=Response,
               responses=_ERRORS)
def delete_scene(name: SkillName, service: ServiceDep) -> Response:
    """Clear the skill's scene (a new, empty version: live streams hear of it too)."""
    service.put_scene(name, [])
    return Response(status_code=status.HTTP_204_NO_CONTENT)
