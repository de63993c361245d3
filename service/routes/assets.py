"""``/v1/assets``: uploaded terrains, buildings / ground-zone GeoJSON, meshes and grid profiles, per API key."""

import hashlib
import os
import shutil
import tempfile
from pathlib import Path

from fastapi import APIRouter, Request, Response
from starlette.concurrency import run_in_threadpool
from starlette.datastructures import UploadFile

from bentray.service.deps import OwnerDep, ServicesDep
from bentray.service.errors import (
    InvalidInputError,
    NotFoundError,
    QueueFullError,
    UnsupportedMediaError,
    UploadTooLargeError,
)
from bentray.service.layout import file_name_problem
from bentray.service.models import AssetInfo
from bentray.service.openapi import AUTH, BODY, error_responses
from bentray.service.uploads import UPLOAD_KINDS, default_kind
from bentray.service.validation import ValidationBusy, ValidationTimeout

router = APIRouter(tags=["assets"])
COPY_CHUNK = 1 << 20

_ASSET_BODY = {
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


async def save_upload(upload: UploadFile, dest: Path, limit: int) -> tuple[int, str]:
    """Copy an uploaded part to ``dest`` (streamed); 413 past ``limit`` bytes. Returns (size, sha256)."""
    digest = hashlib.sha256()
    size = 0
    dest.parent.mkdir(parents=True, exist_ok=True)
    with open(dest, "wb") as fh:
        while chunk := await upload.read(COPY_CHUNK):
            size += len(chunk)
            if size > limit:
                raise UploadTooLargeError(f"file {upload.filename!r} exceeds this server's limit of {limit:,} bytes")
            digest.update(chunk)
            fh.write(chunk)
    return size, digest.hexdigest()


def _asset_info(record: object) -> AssetInfo:
    return AssetInfo.model_validate(record, from_attributes=True)


@router.post(
    "/v1/assets",
    status_code=201,
    response_model=AssetInfo,
    openapi_extra=_ASSET_BODY,
    responses=error_responses(*AUTH, *BODY, 429),
)
async def upload_asset(request: Request, services: ServicesDep, owner: OwnerDep) -> AssetInfo:
    """Upload a terrain, buildings or ground-zone GeoJSON (kind ground_zones), obstacle mesh or grid profile;
    jobs name it in their file fields."""
    settings, layout = services.settings, services.layout
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
            size, sha = await save_upload(upload, tmp, settings.max_upload_bytes)
            try:
                result = await run_in_threadpool(services.validator.run, "upload", str(tmp), kind)
            except ValidationTimeout as exc:
                raise InvalidInputError.from_lines([f"file: {name}: {exc}"], code="invalid_file") from None
            except ValidationBusy as exc:
                raise QueueFullError(f"{exc}; try again later", settings.retry_after_seconds) from None
            if not result["ok"]:
                raise InvalidInputError.from_lines(result["lines"], code=result["code"])
            os.replace(tmp, layout.asset_path(owner, name))
        finally:
            shutil.rmtree(tmp.parent, ignore_errors=True)
    record = await run_in_threadpool(services.store.put_asset, owner, name, size, sha, result["kind"])
    return _asset_info(record)


@router.get("/v1/assets", response_model=list[AssetInfo], responses=error_responses(*AUTH))
def list_assets(services: ServicesDep, owner: OwnerDep) -> list[AssetInfo]:
    return [_asset_info(a) for a in services.store.list_assets(owner)]


@router.delete("/v1/assets/{name}", status_code=204, responses=error_responses(*AUTH, 404, 422))
def delete_asset(name: str, services: ServicesDep, owner: OwnerDep) -> Response:
    if file_name_problem(name) or not services.store.delete_asset(owner, name):
        raise NotFoundError(f"no asset {name!r}")
    services.layout.asset_path(owner, name).unlink(missing_ok=True)
    return Response(status_code=204)
