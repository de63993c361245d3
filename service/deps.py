"""The service's shared state and its FastAPI dependencies, with their ``Annotated`` aliases in one place.

Routes take ``services: ServicesDep`` (settings, store, layout, validation pool, supervisor) and
``owner: OwnerDep`` (the owner id of the request's API key; 401 without a valid key when keys are
configured, the single local user otherwise).
"""

import hmac
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Annotated

from fastapi import Depends, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from bentray.service.errors import AuthError, NotFoundError
from bentray.service.layout import JOB_ID_RE, DataLayout
from bentray.service.models import SceneInfo
from bentray.service.settings import LOCAL_OWNER, Settings, owner_of_key
from bentray.service.store import JobRecord, JobStore
from bentray.service.validation import ValidationPool

if TYPE_CHECKING:
    from bentray.service.worker import Supervisor

__all__ = ["OwnerDep", "Services", "ServicesDep", "bearer", "current_owner", "get_services"]


@dataclass
class Services:
    """Everything a route needs; one per app (``app.state.services``)."""

    settings: Settings
    store: JobStore
    layout: DataLayout
    validator: ValidationPool
    start_workers: bool = True
    key_owners: list[tuple[bytes, str]] = field(default_factory=list)
    supervisor: "Supervisor | None" = None
    scenes: list[SceneInfo] | None = None

    @classmethod
    def create(cls, settings: Settings, *, start_workers: bool) -> "Services":
        settings.data_dir.mkdir(parents=True, exist_ok=True)
        return cls(
            settings=settings,
            store=JobStore(settings.db_path),
            layout=DataLayout(settings.data_dir),
            validator=ValidationPool(settings.validation_seconds, settings.validation_processes),
            start_workers=start_workers,
            key_owners=[(k.encode(), owner_of_key(k)) for k in settings.api_keys],
        )

    def owned_job(self, job_id: str, owner: str) -> JobRecord:
        """The job ``job_id`` of ``owner``; 404 for an unknown id and for another owner's job alike."""
        record = self.store.get(job_id, owner) if JOB_ID_RE.match(job_id) else None
        if record is None:
            raise NotFoundError(f"no job {job_id!r}")
        return record


def get_services(request: Request) -> Services:
    services = request.app.state.services
    assert isinstance(services, Services)
    return services


ServicesDep = Annotated[Services, Depends(get_services)]

bearer = HTTPBearer(auto_error=False, description="an API key from BENTRAY_API_KEYS")


def current_owner(
    services: ServicesDep, credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)]
) -> str:
    """Owner id of the request's bearer key (constant-time comparison with every configured key)."""
    if not services.key_owners:
        return LOCAL_OWNER
    if credentials is None or credentials.scheme.lower() != "bearer":
        raise AuthError("missing API key: send 'Authorization: Bearer <key>'")
    token = credentials.credentials.encode()
    owner = None
    for key, key_owner in services.key_owners:  # compare with every key: time does not tell which matched
        if hmac.compare_digest(key, token):
            owner = key_owner
    if owner is None:
        raise AuthError("unknown API key")
    return owner


OwnerDep = Annotated[str, Depends(current_owner)]
