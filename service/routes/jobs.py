"""``/v1/jobs``: submit (validated in a helper process under a time limit), list, status, cancel, results."""

import shutil
from pathlib import Path
from typing import Any

from fastapi import APIRouter, Request, Response
from fastapi.responses import FileResponse
from starlette.concurrency import run_in_threadpool
from starlette.datastructures import UploadFile

from bentray.engine.writers import OUTPUT_FILES
from bentray.service.deps import OwnerDep, Services, ServicesDep
from bentray.service.errors import (
    InvalidInputError,
    JobStateError,
    NotFoundError,
    QueueFullError,
    UnsupportedMediaError,
)
from bentray.service.layout import file_name_problem
from bentray.service.models import JobInfo, JobList
from bentray.service.openapi import AUTH, BODY, error_responses
from bentray.service.routes.assets import save_upload
from bentray.service.store import JobRecord, JobStatus, QueueFull, new_job_id
from bentray.service.uploads import UploadKind, default_kind
from bentray.service.validation import JobLimits, ValidationBusy, ValidationTimeout

__all__ = ["MEDIA_TYPES", "router"]

router = APIRouter(tags=["jobs"])

# Result file -> content type. The VTK XML files carry appended binary data: not plain XML text.
MEDIA_TYPES: dict[str, str] = {
    "field.vti": "application/vnd.vtk.imagedata+xml",
    "rays.vtp": "application/vnd.vtk.polydata+xml",
    "mesh.vtu": "application/vnd.vtk.unstructuredgrid+xml",
    "rays.csv": "text/csv; charset=utf-8",
    "receivers.csv": "text/csv; charset=utf-8",
    "arrivals.csv": "text/csv; charset=utf-8",
    "report.json": "application/json",
    "preview.png": "image/png",
}
assert set(MEDIA_TYPES) == set(OUTPUT_FILES)
MAX_FILES_PER_JOB = 64

_JOB_BODY = {
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
                            "description": "input files named by the job (terrain, buildings, zones, obstacles, grid)",
                        },
                    },
                }
            },
        },
    }
}


def job_info(record: JobRecord) -> JobInfo:
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


def _kind_for(field: str, name: str) -> UploadKind | None:
    if field.startswith("scene.terrain."):
        return "terrain"
    if field.startswith("scene.buildings.obstacles."):
        return "obstacle"
    if field.startswith("scene.buildings."):
        return "buildings"
    if field.startswith("scene.ground_zones."):
        return "ground_zones"
    if field.startswith("profile."):
        return "grid"
    return default_kind(name)


def _utf8(data: bytes) -> str:
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InvalidInputError.from_lines([f"job: not UTF-8 text (byte {exc.start})"], code="invalid_json") from None


async def _read_submission(request: Request, services: Services, job_dir: Path) -> tuple[str, dict[str, Path]]:
    """The job text and the uploaded files (saved under job_dir/upload) by name."""
    limit = services.settings.max_upload_bytes
    ctype = request.headers.get("content-type", "")
    if ctype.startswith("application/json"):
        return _utf8(await request.body()), {}
    if not ctype.startswith("multipart/form-data"):
        raise UnsupportedMediaError(
            "send the job as application/json, or as multipart/form-data with a 'job' part and 'files' parts"
        )
    files: dict[str, Path] = {}
    async with request.form(max_files=MAX_FILES_PER_JOB + 1, max_fields=8) as form:
        job_part = form.get("job")
        if isinstance(job_part, UploadFile):
            text = _utf8(await job_part.read(limit + 1))
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
            await save_upload(part, dest, limit)
            files[name] = dest
    return text, files


def _place_inputs(
    services: Services, refs: list[tuple[str, str]], owner: str, uploaded: dict[str, Path], inputs: Path
) -> list[tuple[str, str, str]]:
    """Place every file the job names in ``inputs`` (uploaded with it, or a copy of an asset); return the
    (field, name, kind) of those uploaded with the job (assets were read when they were uploaded)."""
    lines: list[str] = []
    placed: list[tuple[str, str, Path]] = []
    for field, name in refs:
        problem = file_name_problem(name)
        if problem:
            lines.append(f"{field}: {problem}; upload the file with the job or as an asset and name it here")
            continue
        if name in uploaded:
            placed.append((field, name, uploaded[name]))
            continue
        if services.store.get_asset(owner, name) is None:
            lines.append(
                f"{field}: no file {name!r} was uploaded with the job, and there is no asset of that name "
                "(POST /v1/assets)"
            )
            continue
        placed.append((field, name, services.layout.asset_path(owner, name)))
    if lines:
        raise InvalidInputError.from_lines(lines)
    inputs.mkdir(parents=True, exist_ok=True)
    to_check: list[tuple[str, str, str]] = []
    for field, name, src in placed:
        dest = inputs / name
        if not dest.exists():
            shutil.copyfile(src, dest)  # a copy: replacing the asset later does not change this job
        kind = _kind_for(field, name)
        if src in uploaded.values() and kind is not None:
            to_check.append((field, name, kind))
    return to_check


def _limits(services: Services) -> JobLimits:
    s = services.settings
    return JobLimits(
        max_rays=s.max_rays,
        max_field_points=s.max_field_points,
        max_memory_bytes=s.max_job_memory_bytes,
        max_field_deposits=s.max_field_deposits,
        max_ray_steps=s.max_ray_steps,
        threads=s.threads_per_job,
        max_mesh_seconds=s.max_mesh_seconds,
    )


def _validate(services: Services, text: str, owner: str, uploaded: dict[str, Path], inputs: Path) -> str:
    """Both validation stages (helper process, time limit) around placing the inputs; the job's name."""
    try:
        limits = _limits(services)
        first = services.validator.run("text", text, limits)
        if not first["ok"]:
            raise InvalidInputError.from_lines(first["lines"], code=first["code"])
        checks = _place_inputs(services, [tuple(r) for r in first["refs"]], owner, uploaded, inputs)
        mesh_seconds = None if first.get("mesh_known", True) else limits.max_mesh_seconds
        second = services.validator.run("scene", text, str(inputs), checks, mesh_seconds)
    except ValidationTimeout as exc:
        raise InvalidInputError.from_lines([f"job: {exc}; the job is refused"], code="validation_timeout") from None
    except ValidationBusy as exc:
        raise QueueFullError(f"{exc}; try again later", services.settings.retry_after_seconds) from None
    if not second["ok"]:
        raise InvalidInputError.from_lines(second["lines"], code=second["code"])
    return str(first["name"])


@router.post(
    "/v1/jobs",
    status_code=202,
    response_model=JobInfo,
    openapi_extra=_JOB_BODY,
    responses=error_responses(*AUTH, *BODY, 429),
)
async def submit_job(request: Request, response: Response, services: ServicesDep, owner: OwnerDep) -> JobInfo:
    """Queue a job (the job JSON of ``scenes/``); files it names come with it or from assets.

    Validated before it is queued: schema, server limits, the cost model's memory, work and mesh-time budgets,
    the scene (overlaps, sources above the ground) and the medium (sound speed within the physical
    range); any problem is a 422 naming the field.
    """
    job_id = new_job_id()
    layout, settings = services.layout, services.settings
    job_dir = layout.job_dir(job_id)
    try:
        text, uploaded = await _read_submission(request, services, job_dir)
        name = await run_in_threadpool(_validate, services, text, owner, uploaded, layout.inputs(job_id))
        shutil.rmtree(job_dir / "upload", ignore_errors=True)
        try:
            record = await run_in_threadpool(services.store.create_job, job_id, owner, name, text, settings.max_queue)
        except QueueFull as exc:
            raise QueueFullError(f"{exc}; try again later", settings.retry_after_seconds) from None
    except BaseException:
        layout.remove_job_files(job_id)
        raise
    response.headers["Location"] = f"/v1/jobs/{job_id}"
    return job_info(record)


@router.get("/v1/jobs", response_model=JobList, responses=error_responses(*AUTH, 422))
def list_jobs(services: ServicesDep, owner: OwnerDep, status: JobStatus | None = None, limit: int = 100) -> JobList:
    return JobList(jobs=[job_info(r) for r in services.store.list(owner, status, max(1, min(limit, 1000)))])


@router.get("/v1/jobs/{job_id}", response_model=JobInfo, responses=error_responses(*AUTH, 404, 422))
def get_job(job_id: str, services: ServicesDep, owner: OwnerDep) -> JobInfo:
    return job_info(services.owned_job(job_id, owner))


@router.delete(
    "/v1/jobs/{job_id}",
    response_model=JobInfo,
    responses={
        202: {"description": "cancelling a running job", "model": JobInfo},
        204: {"description": "deleted"},
        **error_responses(*AUTH, 404, 422),
    },
)
def delete_job(job_id: str, services: ServicesDep, owner: OwnerDep, response: Response) -> Any:
    """Cancel a queued or running job (its process is stopped within seconds); delete a finished one."""
    record = services.owned_job(job_id, owner)
    if record.finished:
        services.store.delete(job_id)
        services.layout.remove_job_files(job_id)
        return Response(status_code=204)
    updated = services.store.request_cancel(job_id)
    if updated is None:
        raise NotFoundError(f"no job {job_id!r}")
    response.status_code = 200 if updated.finished else 202
    return job_info(updated)


@router.get(
    "/v1/jobs/{job_id}/results/{name}",
    response_class=FileResponse,
    responses={200: {"content": {t: {} for t in MEDIA_TYPES.values()}}, **error_responses(*AUTH, 404, 409, 422)},
)
def get_result(job_id: str, name: str, services: ServicesDep, owner: OwnerDep) -> FileResponse:
    """Download one result file (streamed)."""
    record = services.owned_job(job_id, owner)
    if name not in MEDIA_TYPES:
        raise NotFoundError(f"no result {name!r}; result names are {', '.join(MEDIA_TYPES)}")
    if record.status is not JobStatus.SUCCEEDED:
        raise JobStateError(f"job {job_id} is {record.status.value}; results exist once it succeeded")
    if name not in record.files:
        raise NotFoundError(f"job {job_id} did not produce {name} (outputs: {', '.join(record.files)})")
    return FileResponse(services.layout.results(job_id) / name, media_type=MEDIA_TYPES[name], filename=name)
