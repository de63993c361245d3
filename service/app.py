"""The FastAPI application: routes under ``/v1``, OpenAPI at ``/docs``.

A thin layer over the store and the supervisor: routes validate, write the job's input files and a
queued row, and return at once (202); job processes do the work (:mod:`bentray.service.worker`).
CPU-bound checks (schema validation, reading uploaded meshes) run in the thread pool, never on the
event loop. Authentication: ``Authorization: Bearer <key>`` with a key from the settings; a job or
asset of another key is answered 404, exactly like an unknown id. No key configured: one local user.
"""

# No `from __future__ import annotations`: FastAPI resolves the route annotations (the local Owner alias).
import hashlib
import hmac
import os
import shutil
import tempfile
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Annotated, Any

from fastapi import Depends, FastAPI, Request, Response
from fastapi.responses import FileResponse
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from pydantic import ValidationError
from starlette.concurrency import run_in_threadpool
from starlette.datastructures import UploadFile
from starlette.types import ASGIApp, Receive, Scope, Send

import bentray
from bentray.engine.writers import OUTPUT_FILES
from bentray.scenes.schema import Job, JobFileError, parse_job_text
from bentray.service.errors import (
    AuthError,
    InvalidInputError,
    JobStateError,
    LengthRequiredError,
    NotFoundError,
    QueueFullError,
    UnsupportedMediaError,
    UploadTooLargeError,
    install_error_handlers,
    job_validation_error,
)
from bentray.service.layout import JOB_ID_RE, DataLayout, file_name_problem
from bentray.service.models import AssetInfo, Health, JobInfo, JobList, SceneInfo
from bentray.service.settings import LOCAL_OWNER, Settings, owner_of_key
from bentray.service.store import JobRecord, JobStatus, JobStore, QueueFull, new_job_id
from bentray.service.uploads import UPLOAD_KINDS, UploadKind, check_upload, default_kind

__all__ = ["MEDIA_TYPES", "create_app"]

# Result file -> content type. The VTK XML files carry appended binary data: not plain XML text.
MEDIA_TYPES: dict[str, str] = {
    "field.vti": "application/vnd.vtk.imagedata+xml",
    "rays.vtp": "application/vnd.vtk.polydata+xml",
    "mesh.vtu": "application/vnd.vtk.unstructuredgrid+xml",
    "rays.csv": "text/csv; charset=utf-8",
    "report.json": "application/json",
    "preview.png": "image/png",
}
assert set(MEDIA_TYPES) == set(OUTPUT_FILES)
_BODY_SLACK_BYTES = 1 << 20  # a request body may exceed max_upload_bytes by this (job JSON, multipart headers)
_MAX_FILES_PER_JOB = 64
_COPY_CHUNK = 1 << 20
# Keys of job fields that name input files (scene.terrain.file, profile.path, ...).
_FILE_KEYS = {"file", "path"}


# ---------------------------------------------------------------------------------------------
# Request size limit (before any body is read)
# ---------------------------------------------------------------------------------------------
class BodyLimitMiddleware:
    """413 for a POST whose Content-Length exceeds the limit; 411 for a POST body without one."""

    def __init__(self, app: ASGIApp, limit: int) -> None:
        self.app = app
        self.limit = limit

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and scope["method"] in ("POST", "PUT", "PATCH"):
            headers = {k.lower(): v for k, v in scope.get("headers", [])}
            length = headers.get(b"content-length")
            error = None
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
                import json

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


# ---------------------------------------------------------------------------------------------
# Helpers
# ---------------------------------------------------------------------------------------------
def _job_info(record: JobRecord) -> JobInfo:
    base = f"/v1/jobs/{record.id}"
    links = {"self": base}
    if record.status is JobStatus.SUCCEEDED:
        links.update({name: f"{base}/results/{name}" for name in record.files})
    return JobInfo(
        id=record.id,
        name=record.name,
        status=record.status.value,
        stage=record.stage,
        progress=record.progress,
        created_at=record.created_at,
        started_at=record.started_at,
        finished_at=record.finished_at,
        error=record.error,
        attempts=record.attempts,
        cancel_requested=record.cancel_requested,
        results=record.files if record.status is JobStatus.SUCCEEDED else [],
        timings_s=record.timings,
        links=links,
    )


def _file_refs(value: Any, loc: tuple[str | int, ...] = ()) -> list[tuple[str, str]]:
    """(field path, name) of every input file a job names (``file`` / ``path`` keys, any depth)."""
    out: list[tuple[str, str]] = []
    if isinstance(value, dict):
        for key, item in value.items():
            if key in _FILE_KEYS and isinstance(item, str):
                out.append((".".join(str(p) for p in (*loc, key)), item))
            else:
                out.extend(_file_refs(item, (*loc, key)))
    elif isinstance(value, list):
        for i, item in enumerate(value):
            out.extend(_file_refs(item, (*loc, i)))
    return out


def _kind_for(field: str, name: str) -> UploadKind | None:
    if field.startswith("scene.terrain."):
        return "terrain"
    if field.startswith("scene.buildings.obstacles."):
        return "obstacle"
    if field.startswith("scene.buildings."):
        return "buildings"
    if field.startswith("profile."):
        return "grid"
    return default_kind(name)


def _limit_errors(job: Job, settings: Settings) -> list[str]:
    lines = []
    if job.n_rays > settings.max_rays:
        lines.append(
            f"rays: {job.n_rays:,} rays (sources x elevations x azimuths) exceed this server's limit "
            f"of {settings.max_rays:,} rays per job"
        )
    if job.field is not None and job.field.n_points > settings.max_field_points:
        lines.append(
            f"field.shape: {job.field.n_points:,} field points exceed this server's limit of "
            f"{settings.max_field_points:,}"
        )
    return lines


async def _save_upload(upload: UploadFile, dest: Path, limit: int) -> tuple[int, str]:
    """Copy an uploaded part to ``dest`` (streamed); 413 past ``limit`` bytes. Returns (size, sha256)."""
    digest = hashlib.sha256()
    size = 0
    dest.parent.mkdir(parents=True, exist_ok=True)
    with open(dest, "wb") as fh:
        while chunk := await upload.read(_COPY_CHUNK):
            size += len(chunk)
            if size > limit:
                raise UploadTooLargeError(f"file {upload.filename!r} exceeds this server's limit of {limit:,} bytes")
            digest.update(chunk)
            fh.write(chunk)
    return size, digest.hexdigest()


def _document_job_schema(app: FastAPI) -> None:
    """Put the job model into the OpenAPI components (the submit route reads the body itself)."""
    original = app.openapi

    def openapi() -> dict[str, Any]:
        schema = original()
        components = schema.setdefault("components", {}).setdefault("schemas", {})
        if "Job" not in components:
            job_schema = Job.model_json_schema(ref_template="#/components/schemas/{model}")
            components.update(job_schema.pop("$defs", {}))
            components["Job"] = job_schema
        return schema

    app.openapi = openapi  # type: ignore[method-assign]


# ---------------------------------------------------------------------------------------------
# The application
# ---------------------------------------------------------------------------------------------
def create_app(settings: Settings, *, start_workers: bool = True) -> FastAPI:
    """Build the app for ``settings``. With ``start_workers`` and ``settings.workers > 0`` the lifespan
    starts a :class:`bentray.service.worker.Supervisor` (job processes) and stops it on shutdown."""
    layout = DataLayout(settings.data_dir)
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    store = JobStore(settings.db_path)
    state: dict[str, Any] = {"supervisor": None, "scenes": None}

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        supervisor = None
        if start_workers and settings.workers > 0:
            from bentray.service.worker import Supervisor

            supervisor = Supervisor(settings)
            supervisor.start()
            state["supervisor"] = supervisor
        try:
            yield
        finally:
            if supervisor is not None:
                await run_in_threadpool(supervisor.stop)

    app = FastAPI(
        title="bentray",
        version=bentray.__version__,
        lifespan=lifespan,
        docs_url="/docs",
        description="Outdoor-acoustics curved-ray engine as a service: submit a job (scene, profile, rays), "
        "watch it run, download rays.csv, rays.vtp, mesh.vtu, field.vti, preview.png, report.json.",
    )
    install_error_handlers(app)
    _document_job_schema(app)
    app.add_middleware(BodyLimitMiddleware, limit=settings.max_upload_bytes + _BODY_SLACK_BYTES)
    app.state.settings = settings
    app.state.store = store

    bearer = HTTPBearer(auto_error=False, description="an API key from BENTRAY_API_KEYS")
    key_owners = [(k.encode(), owner_of_key(k)) for k in settings.api_keys]

    def current_owner(credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)]) -> str:
        if not key_owners:
            return LOCAL_OWNER
        if credentials is None or credentials.scheme.lower() != "bearer":
            raise AuthError("missing API key: send 'Authorization: Bearer <key>'")
        token = credentials.credentials.encode()
        owner = None
        for key, key_owner in key_owners:  # compare with every key: time does not tell which matched
            if hmac.compare_digest(key, token):
                owner = key_owner
        if owner is None:
            raise AuthError("unknown API key")
        return owner

    Owner = Annotated[str, Depends(current_owner)]

    def owned_job(job_id: str, owner: str) -> JobRecord:
        record = store.get(job_id, owner) if JOB_ID_RE.match(job_id) else None
        if record is None:
            raise NotFoundError(f"no job {job_id!r}")
        return record

    # -- health and scenes ---------------------------------------------------------------------
    @app.get("/v1/health", response_model=Health, tags=["service"])
    async def health() -> Health:
        supervisor = state["supervisor"]
        if settings.workers == 0 or not start_workers:
            sup = "external"
        else:
            sup = "running" if supervisor is not None and supervisor.alive else "stopped"
        return Health(
            status="ok" if sup != "stopped" else "degraded",
            version=bentray.__version__,
            workers=settings.workers,
            supervisor=sup,
            auth="api-keys" if key_owners else "local",
        )

    @app.get("/v1/scenes", response_model=list[SceneInfo], tags=["scenes"])
    def scenes(owner: Owner) -> list[SceneInfo]:
        if state["scenes"] is None:
            from bentray.scenes.library.registry import scene_table

            state["scenes"] = [SceneInfo(**row) for row in scene_table()]
        return list(state["scenes"])

    # -- assets --------------------------------------------------------------------------------
    asset_body = {
        "requestBody": {
            "required": True,
            "content": {
                "multipart/form-data": {
                    "schema": {
                        "type": "object",
                        "required": ["file"],
                        "properties": {
                            "file": {
                                "type": "string",
                                "format": "binary",
                                "description": "the file; its name is the asset name",
                            },
                            "name": {"type": "string", "description": "asset name (default: the uploaded file name)"},
                            "kind": {
                                "type": "string",
                                "enum": list(UPLOAD_KINDS),
                                "description": "default: from the suffix",
                            },
                        },
                    }
                }
            },
        }
    }

    @app.post("/v1/assets", status_code=201, response_model=AssetInfo, tags=["assets"], openapi_extra=asset_body)
    async def upload_asset(request: Request, owner: Owner) -> AssetInfo:
        """Upload a terrain, buildings GeoJSON, obstacle mesh or grid profile; jobs name it in their file fields."""
        if not request.headers.get("content-type", "").startswith("multipart/form-data"):
            raise UnsupportedMediaError("upload assets as multipart/form-data with a 'file' part")
        async with request.form(max_files=1, max_fields=4) as form:
            upload = form.get("file")
            if not isinstance(upload, UploadFile):
                raise InvalidInputError.from_lines(["file: a multipart part 'file' with the file is required"])
            raw_name = form.get("name")
            name = raw_name if isinstance(raw_name, str) and raw_name else (upload.filename or "")
            problem = file_name_problem(name)
            if problem:
                raise InvalidInputError.from_lines([f"name: {problem}"], code="invalid_name")
            kind_text = form.get("kind")
            if kind_text is not None and kind_text not in UPLOAD_KINDS:
                raise InvalidInputError.from_lines([f"kind: must be one of {', '.join(UPLOAD_KINDS)}"])
            kind = kind_text if isinstance(kind_text, str) else default_kind(name)
            if kind is None:
                raise InvalidInputError.from_lines(
                    [f"name: cannot tell the kind of {name!r} from its suffix; give kind ({', '.join(UPLOAD_KINDS)})"]
                )
            dest_dir = layout.asset_dir(owner)
            dest_dir.mkdir(parents=True, exist_ok=True)
            tmp = Path(tempfile.mkdtemp(prefix=".upload.", dir=dest_dir)) / name
            try:
                size, sha = await _save_upload(upload, tmp, settings.max_upload_bytes)
                try:
                    accepted = await run_in_threadpool(check_upload, tmp, kind)  # type: ignore[arg-type]
                except ValueError as exc:
                    raise InvalidInputError.from_lines([f"file: {name}: {exc}"], code="invalid_file") from None
                os.replace(tmp, layout.asset_path(owner, name))
            finally:
                shutil.rmtree(tmp.parent, ignore_errors=True)
        record = await run_in_threadpool(store.put_asset, owner, name, size, sha, accepted)
        return AssetInfo(
            name=record.name, kind=record.kind, size=record.size, sha256=record.sha256, created_at=record.created_at
        )

    @app.get("/v1/assets", response_model=list[AssetInfo], tags=["assets"])
    def list_assets(owner: Owner) -> list[AssetInfo]:
        return [
            AssetInfo(name=a.name, kind=a.kind, size=a.size, sha256=a.sha256, created_at=a.created_at)
            for a in store.list_assets(owner)
        ]

    @app.delete("/v1/assets/{name}", status_code=204, tags=["assets"])
    def delete_asset(name: str, owner: Owner) -> Response:
        if file_name_problem(name) or not store.delete_asset(owner, name):
            raise NotFoundError(f"no asset {name!r}")
        layout.asset_path(owner, name).unlink(missing_ok=True)
        return Response(status_code=204)

    # -- jobs ----------------------------------------------------------------------------------
    job_body = {
        "requestBody": {
            "required": True,
            "content": {
                "application/json": {"schema": {"$ref": "#/components/schemas/Job"}},
                "multipart/form-data": {
                    "schema": {
                        "type": "object",
                        "required": ["job"],
                        "properties": {
                            "job": {"type": "string", "description": "the job JSON (text or a file part)"},
                            "files": {
                                "type": "array",
                                "items": {"type": "string", "format": "binary"},
                                "description": "input files named by the job (terrain, buildings, obstacles, grid)",
                            },
                        },
                    }
                },
            },
        }
    }

    async def _read_submission(request: Request, job_dir: Path) -> tuple[str, dict[str, Path]]:
        """The job text and the uploaded files (saved under job_dir/upload) by name."""
        ctype = request.headers.get("content-type", "")
        if ctype.startswith("application/json"):
            raw = await request.body()
            try:
                return raw.decode("utf-8"), {}
            except UnicodeDecodeError as exc:
                raise InvalidInputError.from_lines(
                    [f"job: not UTF-8 text (byte {exc.start})"], code="invalid_json"
                ) from None
        if not ctype.startswith("multipart/form-data"):
            raise UnsupportedMediaError(
                "send the job as application/json, or as multipart/form-data with a 'job' part and 'files' parts"
            )
        files: dict[str, Path] = {}
        async with request.form(max_files=_MAX_FILES_PER_JOB + 1, max_fields=8) as form:
            job_part = form.get("job")
            if isinstance(job_part, UploadFile):
                job_bytes = await job_part.read(settings.max_upload_bytes + 1)
                try:
                    text = job_bytes.decode("utf-8")
                except UnicodeDecodeError as exc:
                    raise InvalidInputError.from_lines(
                        [f"job: not UTF-8 text (byte {exc.start})"], code="invalid_json"
                    ) from None
            elif isinstance(job_part, str):
                text = job_part
            else:
                raise InvalidInputError.from_lines(["job: a multipart part 'job' with the job JSON is required"])
            for part in form.getlist("files"):
                if not isinstance(part, UploadFile):
                    raise InvalidInputError.from_lines(["files: each 'files' part must be a file"])
                name = part.filename or ""
                problem = file_name_problem(name)
                if problem:
                    raise InvalidInputError.from_lines([f"files: {problem}"], code="invalid_name")
                if name in files:
                    raise InvalidInputError.from_lines([f"files: {name!r} was uploaded twice"])
                dest = job_dir / "upload" / name
                await _save_upload(part, dest, settings.max_upload_bytes)
                files[name] = dest
        return text, files

    def _prepare_inputs(job: Job, owner: str, uploaded: dict[str, Path], inputs: Path) -> None:
        """Check every file the job names and place it in ``inputs`` (uploaded with the job, or an asset)."""
        lines: list[str] = []
        placed: list[tuple[str, str, Path]] = []
        for field, name in _file_refs(job.model_dump(mode="json", exclude_none=True)):
            problem = file_name_problem(name)
            if problem:
                lines.append(f"{field}: {problem}; upload the file with the job or as an asset and name it here")
                continue
            if name in uploaded:
                placed.append((field, name, uploaded[name]))
                continue
            asset = store.get_asset(owner, name)
            if asset is None:
                lines.append(
                    f"{field}: no file {name!r} was uploaded with the job, and there is no asset of that "
                    "name (POST /v1/assets)"
                )
                continue
            placed.append((field, name, layout.asset_path(owner, name)))
        if lines:
            raise InvalidInputError.from_lines(lines)
        inputs.mkdir(parents=True, exist_ok=True)
        for field, name, src in placed:
            dest = inputs / name
            if src.parent != inputs and not dest.exists():
                shutil.copyfile(src, dest)  # a copy: replacing the asset later does not change this job
            if src in uploaded.values():
                kind = _kind_for(field, name)
                if kind is not None:
                    try:
                        check_upload(dest, kind)
                    except ValueError as exc:
                        lines.append(f"{field}: {name}: {exc}")
        if lines:
            raise InvalidInputError.from_lines(lines, code="invalid_file")

    def _validate(text: str, owner: str, uploaded: dict[str, Path], inputs: Path) -> Job:
        try:
            job = parse_job_text(text, origin="job")
        except (ValidationError, JobFileError) as exc:
            raise job_validation_error(exc) from None
        limits = _limit_errors(job, settings)
        if limits:
            raise InvalidInputError.from_lines(limits, code="over_limit")
        _prepare_inputs(job, owner, uploaded, inputs)
        return job

    @app.post(
        "/v1/jobs",
        status_code=202,
        response_model=JobInfo,
        tags=["jobs"],
        openapi_extra=job_body,
        responses={
            422: {"description": "invalid job: `field.path: reason` lines"},
            413: {"description": "upload too large"},
            429: {"description": "queue full"},
        },
    )
    async def submit_job(request: Request, response: Response, owner: Owner) -> JobInfo:
        """Queue a job (the job JSON of ``scenes/``); files it names come with it or from assets."""
        job_id = new_job_id()
        job_dir = layout.job_dir(job_id)
        try:
            text, uploaded = await _read_submission(request, job_dir)
            job = await run_in_threadpool(_validate, text, owner, uploaded, layout.inputs(job_id))
            shutil.rmtree(job_dir / "upload", ignore_errors=True)
            try:
                record = await run_in_threadpool(store.create_job, job_id, owner, job.name, text, settings.max_queue)
            except QueueFull as exc:
                raise QueueFullError(f"{exc}; try again later") from None
        except BaseException:
            layout.remove_job_files(job_id)
            raise
        response.headers["Location"] = f"/v1/jobs/{job_id}"
        return _job_info(record)

    @app.get("/v1/jobs", response_model=JobList, tags=["jobs"])
    def list_jobs(owner: Owner, status: JobStatus | None = None, limit: int = 100) -> JobList:
        return JobList(jobs=[_job_info(r) for r in store.list(owner, status, max(1, min(limit, 1000)))])

    @app.get("/v1/jobs/{job_id}", response_model=JobInfo, tags=["jobs"])
    def get_job(job_id: str, owner: Owner) -> JobInfo:
        return _job_info(owned_job(job_id, owner))

    @app.delete(
        "/v1/jobs/{job_id}",
        tags=["jobs"],
        response_model=JobInfo,
        responses={202: {"description": "cancelling a running job"}, 204: {"description": "deleted"}},
    )
    def delete_job(job_id: str, owner: Owner, response: Response) -> Any:
        """Cancel a queued or running job (its process is stopped within seconds); delete a finished one."""
        record = owned_job(job_id, owner)
        if record.finished:
            store.delete(job_id)
            layout.remove_job_files(job_id)
            return Response(status_code=204)
        updated = store.request_cancel(job_id)
        if updated is None:
            raise NotFoundError(f"no job {job_id!r}")
        response.status_code = 200 if updated.finished else 202
        return _job_info(updated)

    @app.get(
        "/v1/jobs/{job_id}/results/{name}",
        tags=["jobs"],
        response_class=FileResponse,
        responses={200: {"content": {t: {} for t in MEDIA_TYPES.values()}}},
    )
    def get_result(job_id: str, name: str, owner: Owner) -> FileResponse:
        """Download one result file (streamed)."""
        record = owned_job(job_id, owner)
        if name not in MEDIA_TYPES:
            raise NotFoundError(f"no result {name!r}; result names are {', '.join(MEDIA_TYPES)}")
        if record.status is not JobStatus.SUCCEEDED:
            raise JobStateError(f"job {job_id} is {record.status.value}; results exist once it succeeded")
        if name not in record.files:
            raise NotFoundError(f"job {job_id} did not produce {name} (outputs: {', '.join(record.files)})")
        return FileResponse(layout.results(job_id) / name, media_type=MEDIA_TYPES[name], filename=name)

    return app
