"""The OpenAPI contract: every error status a route can answer, documented with the service's error model.

:func:`error_responses` gives a route's ``responses=`` entries (all with :class:`ErrorBody`; 429 with its
``Retry-After`` header); :func:`document_job_schema` puts the job model into the components (the submit
route reads its body itself, so FastAPI cannot see it).
"""

from typing import Any

from fastapi import FastAPI

from bentray.scenes.schema import Job
from bentray.service.models import ErrorBody

__all__ = ["AUTH", "BODY", "error_responses", "document_job_schema"]

_DESCRIPTIONS = {
    400: "malformed request (e.g. a multipart body that cannot be parsed)",
    401: "missing or unknown API key (only when keys are configured)",
    404: "no such job, result or asset (another key's are answered the same)",
    409: "the job is not in a state that allows this (e.g. results of a running job)",
    411: "a request body without Content-Length",
    413: "request body or uploaded file over this server's limit",
    415: "unsupported Content-Type",
    422: "invalid input: one `field.path: reason` line per problem in `detail`, the same in `errors`",
    429: "queue full: try again after `Retry-After` seconds",
}
AUTH = (401,)
BODY = (400, 411, 413, 415, 422)


def error_responses(*codes: int) -> dict[int | str, dict[str, Any]]:
    """``responses=`` entries for the given status codes, each with the ErrorBody model."""
    out: dict[int | str, dict[str, Any]] = {}
    for code in sorted(set(codes)):
        entry: dict[str, Any] = {"model": ErrorBody, "description": _DESCRIPTIONS[code]}
        if code == 429:
            entry["headers"] = {
                "Retry-After": {"description": "seconds to wait before retrying", "schema": {"type": "integer"}}
            }
        out[code] = entry
    return out


def document_job_schema(app: FastAPI) -> None:
    """Put the job model into the OpenAPI components (the submit route reads the body itself)."""
    original = app.openapi

    def openapi() -> dict[str, Any]:
        schema = original()
        components = schema.setdefault("components", {}).setdefault("schemas", {})
        if "Job" not in components:
            job_schema = Job.model_json_schema(ref_template="#/components/schemas/{model}")
            components.update(job_schema.pop("$defs", {}))
            components["Job"] = job_schema
        # FastAPI's own validation-error models are never answered (handlers return ErrorBody)
        for name in ("HTTPValidationError", "ValidationError"):
            components.pop(name, None)
        return schema

    app.openapi = openapi  # type: ignore[method-assign]
