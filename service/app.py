"""The FastAPI application: routes under ``/v1`` (one ``APIRouter`` per resource), OpenAPI at ``/docs``.

A thin layer over the store and the supervisor: routes validate, write the job's input files and a
queued row, and return at once (202); job processes do the work (:mod:`bentray.service.worker`).
Validation (schema, limits, cost model, scene and medium checks, reading uploaded files) runs in helper
processes under a time limit (:mod:`bentray.service.validation`), never on the API's threads or event
loop. Authentication: ``Authorization: Bearer <key>`` with a key from the settings; a job or asset of
another key is answered 404, exactly like an unknown id. No key configured: one local user.
Errors: typed exceptions (:mod:`bentray.service.errors`) mapped to HTTP codes in one place; every error
answer is an ``ErrorBody`` and documented per route (:mod:`bentray.service.openapi`).
"""

import json
import logging
import shutil
import time
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from fastapi import FastAPI
from starlette.concurrency import run_in_threadpool
from starlette.types import ASGIApp, Receive, Scope, Send

import bentray
from bentray.service.deps import Services
from bentray.service.errors import (
    InvalidInputError,
    LengthRequiredError,
    ServiceError,
    UploadTooLargeError,
    install_error_handlers,
)
from bentray.service.layout import JOB_ID_RE
from bentray.service.openapi import document_job_schema
from bentray.service.routes import ROUTERS
from bentray.service.routes.jobs import MEDIA_TYPES
from bentray.service.settings import Settings

__all__ = ["MEDIA_TYPES", "BodyLimitMiddleware", "create_app", "remove_stale_files"]

log = logging.getLogger("bentray.service")
_BODY_SLACK_BYTES = 1 << 20  # a request body may exceed max_upload_bytes by this (job JSON, multipart headers)
STALE_SUBMIT_S = 600.0  # a job folder without a store row this old is a submit that died half-way


class BodyLimitMiddleware:
    """413 for a POST whose Content-Length exceeds the limit; 411 for a POST body without one."""

    def __init__(self, app: ASGIApp, limit: int) -> None:
        self.app = app
        self.limit = limit

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and scope["method"] in ("POST", "PUT", "PATCH"):
            headers = {k.lower(): v for k, v in scope.get("headers", [])}
            length = headers.get(b"content-length")
            error: ServiceError | None = None
            if length is None:
                if headers.get(b"transfer-encoding"):
                    error = LengthRequiredError("send the request body with a Content-Length header")
            elif not length.isdigit():
                error = InvalidInputError.from_lines(["request: invalid Content-Length header"])
            elif int(length) > self.limit:
                error = UploadTooLargeError(
                    f"request body of {int(length):,} bytes exceeds this server's limit of {self.limit:,} bytes"
                )
            if error is not None:
                body = json.dumps(error.body()).encode()
                await send(
                    {
                        "type": "http.response.start",
                        "status": error.status,
                        "headers": [
                            (b"content-type", b"application/json"),
                            (b"content-length", str(len(body)).encode()),
                            (b"connection", b"close"),
                        ],
                    }
                )
                await send({"type": "http.response.body", "body": body})
                return
        await self.app(scope, receive, send)


def remove_stale_files(services: Services) -> int:
    """Remove what a killed server left behind: half-written asset uploads (``.upload.*``) and job
    folders of submits that never got a store row. Returns how many were removed."""
    root = services.settings.data_dir
    removed = 0
    for tmp in (root / "assets").glob("*/.upload.*"):
        shutil.rmtree(tmp, ignore_errors=True)
        removed += 1
    now = time.time()
    for job_dir in (root / "jobs").glob("*"):
        if not JOB_ID_RE.match(job_dir.name) or services.store.get(job_dir.name) is not None:
            continue
        try:
            old = now - job_dir.stat().st_mtime > STALE_SUBMIT_S
        except OSError:
            continue
        if old:
            shutil.rmtree(job_dir, ignore_errors=True)
            removed += 1
    return removed


def create_app(settings: Settings, *, start_workers: bool = True) -> FastAPI:
    """Build the app for ``settings``. With ``start_workers`` and ``settings.workers > 0`` the lifespan
    starts a :class:`bentray.service.worker.Supervisor` (job processes) and stops it on shutdown; it
    also starts the validation helpers and removes stale temporary files."""
    services = Services.create(settings, start_workers=start_workers)

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        await run_in_threadpool(remove_stale_files, services)
        await run_in_threadpool(services.validator.start)
        if start_workers and settings.workers > 0:
            from bentray.service.worker import Supervisor

            services.supervisor = Supervisor(settings)
            services.supervisor.start()
        try:
            yield
        finally:
            if services.supervisor is not None:
                await run_in_threadpool(services.supervisor.stop)
            services.validator.close()

    app = FastAPI(
        title="bentray",
        version=bentray.__version__,
        lifespan=lifespan,
        docs_url="/docs",
        description="Outdoor-acoustics curved-ray engine as a service: submit a job (scene, profile, rays), "
        "watch it run, download rays.csv, rays.vtp, mesh.vtu, field.vti, preview.png, report.json. "
        "Every error answer is an ErrorBody: {error, detail, errors}.",
    )
    install_error_handlers(app)
    document_job_schema(app)
    app.add_middleware(BodyLimitMiddleware, limit=settings.max_upload_bytes + _BODY_SLACK_BYTES)
    app.state.settings = settings
    app.state.store = services.store
    app.state.services = services
    for router in ROUTERS:
        app.include_router(router)
    return app
