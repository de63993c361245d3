"""Typed Python client of the bentray service (httpx).

    from bentray.clients.client import BentrayClient
    with BentrayClient("http://127.0.0.1:8000", api_key=None) as client:
        info = client.submit("scenes/examples/a-ld-fan.json")       # files the job names are uploaded too
        info = client.wait(info.id, progress=True)                 # a text progress bar on stderr
        client.download(info.id, "results/a-ld-fan")                # every result file, streamed

Every call raises :class:`ServiceError` for an HTTP error status, with the server's text
(``field.path: reason`` lines for 422) and status code.
"""

from __future__ import annotations

import builtins
import json
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import IO, Any

import httpx

from bentray.service.models import AssetInfo, Health, JobInfo, JobList, SceneInfo

__all__ = ["DEFAULT_URL", "BentrayClient", "ServiceError", "WaitTimeout", "job_input_files", "text_progress_bar"]

DEFAULT_URL = "http://127.0.0.1:8000"
_DOWNLOAD_CHUNK = 1 << 20


class ServiceError(Exception):
    """An HTTP error from the service: ``status`` code, ``code`` (e.g. ``invalid_job``) and ``detail`` text."""

    def __init__(self, status: int, code: str, detail: str, retry_after_s: float | None = None) -> None:
        super().__init__(f"HTTP {status} {code}: {detail}")
        self.status = status
        self.code = code
        self.detail = detail
        self.retry_after_s = retry_after_s  # a 429's Retry-After (seconds), else None


class WaitTimeout(TimeoutError):
    """:meth:`BentrayClient.wait` gave up before the job finished."""


def _raise_for(response: httpx.Response) -> None:
    if response.is_success:
        return
    try:
        response.read()
        body = response.json()
        code, detail = str(body.get("error", "error")), str(body.get("detail", response.text))
    except (ValueError, AttributeError):
        code, detail = "error", response.text or response.reason_phrase
    retry: float | None = None
    try:
        retry = float(response.headers["retry-after"])
    except (KeyError, ValueError):
        retry = None
    raise ServiceError(response.status_code, code, detail, retry)


def job_input_files(job: dict[str, Any]) -> list[str]:
    """The file names a job dict refers to (``file``/``path`` keys at any depth), in order, once each."""
    names: list[str] = []

    def walk(value: Any) -> None:
        if isinstance(value, dict):
            for key, item in value.items():
                if key in ("file", "path") and isinstance(item, str):
                    if item not in names:
                        names.append(item)
                else:
                    walk(item)
        elif isinstance(value, list):
            for item in value:
                walk(item)

    walk(job)
    return names


def text_progress_bar(stream: IO[str] | None = None, width: int = 30) -> Callable[[JobInfo], None]:
    """A progress callback drawing ``[#####-----]  42% trace`` on one line of ``stream`` (stderr)."""
    out = stream or sys.stderr

    def show(info: JobInfo) -> None:
        filled = int(round(width * info.progress))
        line = f"\r{info.name} [{'#' * filled}{'-' * (width - filled)}] {100 * info.progress:3.0f}% {info.stage:<12}"
        out.write(line)
        if info.finished:
            out.write("\n")
        out.flush()

    return show


class BentrayClient:
    """Client of one service. ``api_key``: a bearer key (None for a local single-user server)."""

    def __init__(
        self,
        base_url: str = DEFAULT_URL,
        api_key: str | None = None,
        timeout_s: float = 60.0,
        transport: httpx.BaseTransport | None = None,
    ) -> None:
        headers = {"Authorization": f"Bearer {api_key}"} if api_key else {}
        self._http = httpx.Client(
            base_url=base_url.rstrip("/"), headers=headers, timeout=timeout_s, transport=transport
        )

    def __enter__(self) -> BentrayClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._http.close()

    def _request(self, method: str, url: str, **kwargs: Any) -> httpx.Response:
        response = self._http.request(method, url, **kwargs)
        _raise_for(response)
        return response

    # -- service -------------------------------------------------------------------------------
    def health(self) -> Health:
        return Health.model_validate(self._request("GET", "/v1/health").json())

    def scenes(self) -> list[SceneInfo]:
        return [SceneInfo.model_validate(row) for row in self._request("GET", "/v1/scenes").json()]

    # -- assets --------------------------------------------------------------------------------
    def upload_asset(self, path: str | Path, name: str | None = None, kind: str | None = None) -> AssetInfo:
        """Upload a scene file (terrain, buildings, obstacle, grid); jobs refer to it by ``name``."""
        path = Path(path)
        data = {k: v for k, v in (("name", name), ("kind", kind)) if v is not None}
        with open(path, "rb") as fh:
            response = self._request("POST", "/v1/assets", files={"file": (name or path.name, fh)}, data=data)
        return AssetInfo.model_validate(response.json())

    def assets(self) -> list[AssetInfo]:
        return [AssetInfo.model_validate(a) for a in self._request("GET", "/v1/assets").json()]

    # -- jobs ----------------------------------------------------------------------------------
    def submit(
        self,
        job: str | Path | dict[str, Any],
        files: Iterable[str | Path] | None = None,
        base_dir: str | Path | None = None,
    ) -> JobInfo:
        """Queue a job: a job file path, or a job dict. Input files it names (terrain, buildings, obstacles,
        grid) are uploaded with it when they exist under ``base_dir`` (default: the job file's folder);
        other names must be assets already uploaded. ``files`` adds explicit files."""
        if isinstance(job, dict):
            text, folder = json.dumps(job), Path(base_dir) if base_dir is not None else None
            names = job_input_files(job)
        else:
            path = Path(job)
            text = path.read_text(encoding="utf-8")
            folder = Path(base_dir) if base_dir is not None else path.absolute().parent
            try:
                names = job_input_files(json.loads(text))
            except ValueError:
                names = []  # the server reports the JSON error
        paths = [Path(f) for f in files or ()]
        if folder is not None:
            given = {p.name for p in paths}
            paths += [folder / n for n in names if (folder / n).is_file() and Path(n).name not in given]
        if not paths:
            response = self._request(
                "POST", "/v1/jobs", content=text.encode("utf-8"), headers={"Content-Type": "application/json"}
            )
            return JobInfo.model_validate(response.json())
        handles = [open(p, "rb") for p in paths]
        try:
            parts: list[tuple[str, tuple[str, Any]]] = [
                ("files", (p.name, fh)) for p, fh in zip(paths, handles, strict=True)
            ]
            parts.insert(0, ("job", ("job.json", text.encode("utf-8"))))
            response = self._request("POST", "/v1/jobs", files=parts)
        finally:
            for fh in handles:
                fh.close()
        return JobInfo.model_validate(response.json())

    def get(self, job_id: str) -> JobInfo:
        return JobInfo.model_validate(self._request("GET", f"/v1/jobs/{job_id}").json())

    def list(self, status: str | None = None, limit: int = 100) -> builtins.list[JobInfo]:
        params: dict[str, Any] = {"limit": limit}
        if status is not None:
            params["status"] = status
        return JobList.model_validate(self._request("GET", "/v1/jobs", params=params).json()).jobs

    def cancel(self, job_id: str) -> JobInfo | None:
        """Cancel a queued or running job (returns its state); delete a finished one (returns None)."""
        response = self._request("DELETE", f"/v1/jobs/{job_id}")
        return None if response.status_code == 204 else JobInfo.model_validate(response.json())

    delete = cancel

    def wait(
        self,
        job_id: str,
        progress: Callable[[JobInfo], None] | bool | None = None,
        poll_s: float = 0.5,
        timeout_s: float | None = None,
    ) -> JobInfo:
        """Poll until the job finished; ``progress`` is called with each state (True: a text bar on stderr).

        Returns the final state (check ``status``: succeeded, failed with ``error``, or cancelled).
        Raises :class:`WaitTimeout` after ``timeout_s`` seconds.
        """
        show = text_progress_bar() if progress is True else (progress or None)
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            info = self.get(job_id)
            if show is not None:
                show(info)
            if info.finished:
                return info
            if deadline is not None and time.monotonic() > deadline:
                raise WaitTimeout(f"job {job_id} is still {info.status} ({info.stage}) after {timeout_s} s")
            time.sleep(poll_s)

    def download(
        self, job_id: str, out_dir: str | Path, names: Sequence[str] | None = None
    ) -> builtins.list[Path]:  # builtins: the method ``list`` shadows the type here
        """Stream result files (default: all of a succeeded job) into ``out_dir``; returns the paths.

        Each file is written to a temporary name and renamed when complete.
        """
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        wanted = list(names) if names is not None else self.get(job_id).results
        written = []
        for name in wanted:
            if Path(name).name != name:
                raise ValueError(f"result names are plain file names, got {name!r}")
            tmp = out / f".{name}.part"
            with self._http.stream("GET", f"/v1/jobs/{job_id}/results/{name}") as response:
                _raise_for(response)
                with open(tmp, "wb") as fh:
                    for chunk in response.iter_bytes(_DOWNLOAD_CHUNK):
                        fh.write(chunk)
            tmp.replace(out / name)
            written.append(out / name)
        return written
