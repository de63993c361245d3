"""``GET /v1/health``: liveness and configuration summary (no API key needed)."""

from fastapi import APIRouter

import bentray
from bentray.service.deps import ServicesDep
from bentray.service.models import Health

router = APIRouter(tags=["service"])


@router.get("/v1/health", response_model=Health)
async def health(services: ServicesDep) -> Health:
    supervisor = services.supervisor
    if services.settings.workers == 0 or not services.start_workers:
        sup = "external"
    else:
        sup = "running" if supervisor is not None and supervisor.alive else "stopped"
    return Health(
        status="ok" if sup != "stopped" else "degraded",
        version=bentray.__version__,
        workers=services.settings.workers,
        supervisor=sup,
        auth="api-keys" if services.key_owners else "local",
    )
