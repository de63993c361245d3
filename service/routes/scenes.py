"""``GET /v1/scenes``: the built-in scenes."""

from fastapi import APIRouter

from bentray.service.deps import OwnerDep, ServicesDep
from bentray.service.models import SceneInfo
from bentray.service.openapi import AUTH, error_responses

router = APIRouter(tags=["scenes"])


@router.get("/v1/scenes", response_model=list[SceneInfo], responses=error_responses(*AUTH))
def scenes(services: ServicesDep, owner: OwnerDep) -> list[SceneInfo]:
    if services.scenes is None:
        from bentray.scenes.library.registry import scene_table

        services.scenes = [SceneInfo(**row) for row in scene_table()]
    return list(services.scenes)
