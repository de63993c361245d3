"""Typed service errors and their HTTP status codes, in one place.

Routes raise these (never ``HTTPException``); :func:`install_error_handlers` turns them, pydantic
``ValidationError`` of a job and FastAPI's own request validation errors into JSON bodies::

    {"error": "invalid_job", "detail": "rays.elevation_deg.count: Input should be ...", "errors": [...]}

``detail`` is the human text: for 422 it holds one ``field.path: reason`` line per problem, the same
text as :func:`bentray.scenes.schema.format_validation_error` (and ``bentray run``'s exit-2 message);
``errors`` lists the same as ``{"field": ..., "reason": ...}`` objects.
"""

from __future__ import annotations

import logging
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import ValidationError
from starlette.exceptions import HTTPException as StarletteHTTPException

from bentray.scenes.schema import JobFileError, format_validation_error

__all__ = [
    "ERROR_CODES",
    "AuthError",
    "BadRequestError",
    "InvalidInputError",
    "JobStateError",
    "LengthRequiredError",
    "NotFoundError",
    "QueueFullError",
    "ServiceError",
    "UnsupportedMediaError",
    "UploadTooLargeError",
    "install_error_handlers",
    "job_validation_error",
    "lines_to_errors",
]


log = logging.getLogger("bentray.service")


class ServiceError(Exception):
    """Base: ``status`` is the HTTP code, ``code`` a stable machine name, ``detail`` the text,
    ``headers`` extra response headers."""

    status = 500
    code = "internal"

    def __init__(self, detail: str, errors: list[dict[str, str]] | None = None) -> None:
        super().__init__(detail)
        self.detail = detail
        self.errors = errors or []
        self.headers: dict[str, str] = {}

    def body(self) -> dict[str, Any]:
        body: dict[str, Any] = {"error": self.code, "detail": self.detail}
        if self.errors:
            body["errors"] = self.errors
        return body


class InvalidInputError(ServiceError):
    """A job, upload or name that cannot be accepted: detail is ``field.path: reason`` lines."""

    status = 422
    code = "invalid_job"

    @classmethod
    def from_lines(cls, lines: list[str], code: str | None = None) -> InvalidInputError:
        err = cls("\n".join(lines), lines_to_errors(lines))
        if code is not None:
            err.code = code
        return err


class BadRequestError(ServiceError):
    """A request the server cannot even parse: a malformed multipart body, a bad header."""

    status = 400
    code = "bad_request"


class AuthError(ServiceError):
    status = 401
    code = "unauthorized"

    def __init__(self, detail: str, errors: list[dict[str, str]] | None = None) -> None:
        super().__init__(detail, errors)
        self.headers = {"WWW-Authenticate": "Bearer"}


class NotFoundError(ServiceError):
    """Unknown id, or a job of another API key (indistinguishable on purpose)."""

    status = 404
    code = "not_found"


class JobStateError(ServiceError):
    """The job exists but is not in a state that allows the request (e.g. results of a running job)."""

    status = 409
    code = "conflict"


class LengthRequiredError(ServiceError):
    status = 411
    code = "length_required"


class UnsupportedMediaError(ServiceError):
    status = 415
    code = "unsupported_media_type"


class UploadTooLargeError(ServiceError):
    status = 413
    code = "too_large"


class QueueFullError(ServiceError):
    """Too many queued jobs; ``Retry-After`` says when to try again (seconds)."""

    status = 429
    code = "queue_full"

    def __init__(self, detail: str, retry_after_s: int = 30) -> None:
        super().__init__(detail)
        self.headers = {"Retry-After": str(int(retry_after_s))}


class MethodNotAllowedError(ServiceError):
    status = 405
    code = "method_not_allowed"


# HTTP status -> the typed error answering it (the one mapping; routes raise these, never HTTPException).
ERROR_CODES: dict[int, type[ServiceError]] = {
    400: BadRequestError,
    401: AuthError,
    404: NotFoundError,
    405: MethodNotAllowedError,
    409: JobStateError,
    411: LengthRequiredError,
    413: UploadTooLargeError,
    415: UnsupportedMediaError,
    422: InvalidInputError,
    429: QueueFullError,
    500: ServiceError,
}


def lines_to_errors(lines: list[str]) -> list[dict[str, str]]:
    """``field.path: reason`` lines -> ``[{"field": "field.path", "reason": "reason"}]``."""
    out = []
    for line in lines:
        field, sep, reason = line.partition(": ")
        out.append({"field": field, "reason": reason} if sep else {"field": "job", "reason": line})
    return out


def job_validation_error(exc: ValidationError | JobFileError) -> InvalidInputError:
    """The 422 error for a job that failed parsing (invalid JSON) or the schema."""
    if isinstance(exc, ValidationError):
        return InvalidInputError.from_lines(format_validation_error(exc).splitlines())
    text = " ".join(str(exc).split())  # parse_job_text(origin="job") already starts with "job: "
    return InvalidInputError.from_lines([text if text.startswith("job: ") else f"job: {text}"], code="invalid_json")


def _request_error_lines(exc: RequestValidationError) -> list[str]:
    lines = []
    for err in exc.errors():
        loc = [str(p) for p in err.get("loc", ()) if p not in ("body", "query", "path", "header", "form")]
        lines.append(f"{'.'.join(loc) or 'request'}: {err.get('msg', 'invalid')}")
    return lines


def install_error_handlers(app: FastAPI) -> None:
    """Register the one mapping from error types to responses on ``app``: every error answer of the
    service, starlette's own (unknown route, multipart parse errors) and unexpected ones (500) included,
    is an :class:`bentray.service.models.ErrorBody`."""

    def respond(err: ServiceError) -> JSONResponse:
        return JSONResponse(err.body(), status_code=err.status, headers=err.headers or None)

    async def service_error(request: Request, exc: Exception) -> JSONResponse:
        assert isinstance(exc, ServiceError)
        return respond(exc)

    async def request_validation(request: Request, exc: Exception) -> JSONResponse:
        assert isinstance(exc, RequestValidationError)
        return respond(InvalidInputError.from_lines(_request_error_lines(exc), code="invalid_request"))

    async def starlette_error(request: Request, exc: Exception) -> JSONResponse:
        assert isinstance(exc, StarletteHTTPException)
        kind = ERROR_CODES.get(exc.status_code)
        detail = str(exc.detail) if exc.detail else "error"
        if kind is None or kind is ServiceError:
            err = ServiceError(detail)
            err.status = exc.status_code
            err.code = "error"
        elif kind is InvalidInputError:
            err = InvalidInputError.from_lines([f"request: {detail}"], code="invalid_request")
        elif kind is QueueFullError:
            err = QueueFullError(detail)
        else:
            err = kind(f"request: {detail}" if exc.status_code == 400 else detail)
        return respond(err)

    async def unexpected(request: Request, exc: Exception) -> JSONResponse:
        log.exception("unexpected error answering %s %s", request.method, request.url.path)
        return respond(ServiceError("internal server error"))

    app.add_exception_handler(ServiceError, service_error)
    app.add_exception_handler(RequestValidationError, request_validation)
    app.add_exception_handler(StarletteHTTPException, starlette_error)
    app.add_exception_handler(Exception, unexpected)
