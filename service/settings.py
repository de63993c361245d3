"""Service configuration, read once from the environment and checked at start-up (fail fast).

Environment variables (all optional):

| variable | default | meaning |
| --- | --- | --- |
| ``BENTRAY_API_KEYS`` | none | comma-separated bearer keys; each key sees only its own jobs and assets |
| ``BENTRAY_API_KEYS_FILE`` | none | file with one key per line (``#`` comments); merged with the above |
| ``BENTRAY_DATA_DIR`` | ``./bentray-data`` | job store (SQLite), inputs, results, assets |
| ``BENTRAY_MAX_RAYS`` | 2,000,000 | rays per job (sources x elevations x azimuths) |
| ``BENTRAY_MAX_FIELD_POINTS`` | 5,000,000 | field grid points per job |
| ``BENTRAY_MAX_UPLOAD_BYTES`` | 64 MiB | one uploaded file (terrain, buildings, ground zones, mesh, grid) |
| ``BENTRAY_MAX_QUEUE`` | 100 | queued jobs (not yet running) across all users; more -> 429 |
| ``BENTRAY_MAX_JOB_SECONDS`` | 3600 | run time of one attempt; longer -> failed |
| ``BENTRAY_RETENTION_DAYS`` | 7 | finished jobs and assets older than this are deleted |
| ``BENTRAY_WORKERS`` | 1 | concurrent job processes started by ``bentray serve`` (0: API only) |
| ``BENTRAY_MAX_JOB_MEMORY_BYTES`` | min(8 GiB, half this machine) | estimated memory of one job (paths, field, rays) |
| ``BENTRAY_MAX_FIELD_DEPOSITS`` | 2e10 | estimated field samples of one job (scenes/cost.py) |
| ``BENTRAY_MAX_RAY_STEPS`` | 5e10 | estimated cell crossings of one job (scenes/cost.py) |
| ``BENTRAY_MAX_MESH_SECONDS`` | 600 | estimated media-mesh build of one job (scenes/cost.py; ``bentray run`` too) |
| ``BENTRAY_VALIDATION_SECONDS`` | 10 | time limit of submit-time validation (its own process); longer -> 422 |
| ``BENTRAY_RETRY_AFTER_SECONDS`` | 30 | ``Retry-After`` of a 429 (queue full) |
| ``BENTRAY_DASK_SCHEDULER`` | none | Dask scheduler (``tcp://host:8786``) for the ray batches (none: in-process) |

No key configured means a single local user: the server then refuses to bind anything but a
loopback address (see :func:`check_bind_host`).
"""

from __future__ import annotations

import hashlib
import ipaddress
import os
from collections.abc import Mapping
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from bentray.scenes.cost import DEFAULT_MESH_SECONDS, machine_memory_bytes

__all__ = ["LOCAL_OWNER", "Settings", "SettingsError", "check_bind_host", "owner_of_key"]

LOCAL_OWNER = "local"  # owner id of every job when no API key is configured
_MIN_KEY_CHARS = 16  # a shorter bearer key is guessable; refuse it at start-up


def _default_job_memory() -> int:
    machine = machine_memory_bytes()
    return min(8 * 2**30, machine // 2) if machine > 0 else 8 * 2**30


class SettingsError(ValueError):
    """Invalid service configuration (raised at start-up, before anything listens)."""


def owner_of_key(key: str) -> str:
    """The owner id stored with a job: SHA-256 of the key, hex, first 32 characters (keys are never stored)."""
    return hashlib.sha256(key.encode("utf-8")).hexdigest()[:32]


class Settings(BaseModel):
    """Service settings. Build with :meth:`from_env` (or directly in tests); immutable."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    api_keys: tuple[str, ...] = ()
    data_dir: Path = Path("bentray-data")
    max_rays: int = Field(default=2_000_000, ge=1)
    max_field_points: int = Field(default=5_000_000, ge=1)
    max_upload_bytes: int = Field(default=64 * 2**20, ge=1024)
    max_queue: int = Field(default=100, ge=1)
    max_job_seconds: float = Field(default=3600.0, gt=0)
    retention_days: float = Field(default=7.0, gt=0)
    workers: int = Field(default=1, ge=0, le=256)
    # Dask scheduler address for the ray batches of every job (None: the job process runs them itself).
    dask_scheduler: str | None = None
    # A job whose worker died (or whose server stopped) runs again once; after that it fails.
    max_attempts: int = Field(default=2, ge=1, le=10)
    # Job processes run at this niceness so that the API keeps answering while they hold the CPU.
    worker_nice: int = Field(default=10, ge=0, le=19)
    # Supervisor loop period (s): how fast cancel, progress and finished children are noticed.
    poll_seconds: float = Field(default=0.2, gt=0, le=5)
    # The cost model's budgets (bentray.scenes.cost): a job over one is refused with a 422 at submit.
    max_job_memory_bytes: int = Field(default_factory=_default_job_memory, ge=2**20)
    max_field_deposits: float = Field(default=2e10, gt=0)
    max_ray_steps: float = Field(default=5e10, gt=0)
    max_mesh_seconds: float = Field(default=DEFAULT_MESH_SECONDS, gt=0)
    # Submit-time validation runs in helper processes with this time limit (a longer one -> 422).
    validation_seconds: float = Field(default=10.0, gt=0, le=600)
    validation_processes: int = Field(default=2, ge=1, le=64)
    retry_after_seconds: int = Field(default=30, ge=1, le=86400)

    @field_validator("api_keys")
    @classmethod
    def _good_keys(cls, keys: tuple[str, ...]) -> tuple[str, ...]:
        for i, key in enumerate(keys):
            if len(key) < _MIN_KEY_CHARS or any(ch.isspace() for ch in key):
                raise ValueError(f"API key {i + 1} must be at least {_MIN_KEY_CHARS} characters without spaces")
        if len(set(keys)) != len(keys):
            raise ValueError("the same API key is listed twice")
        return keys

    @property
    def owners(self) -> dict[str, str]:
        """owner id -> key for every configured key (empty: single local user)."""
        return {owner_of_key(k): k for k in self.api_keys}

    @property
    def threads_per_job(self) -> int:
        """numba threads of one job process (the supervisor's split of this machine's cores)."""
        return max(1, (os.cpu_count() or 1) // max(self.workers, 1))

    @property
    def db_path(self) -> Path:
        return self.data_dir / "jobs.sqlite3"

    @classmethod
    def from_env(cls, environ: Mapping[str, str] | None = None, **overrides: object) -> Settings:
        """Read ``BENTRAY_*`` variables (see the module docstring); ``overrides`` win (CLI flags).

        Raises :class:`SettingsError` naming the variable for any bad value or unreadable key file.
        """
        env = os.environ if environ is None else environ
        values: dict[str, object] = {}
        keys = [k.strip() for k in env.get("BENTRAY_API_KEYS", "").split(",") if k.strip()]
        key_file = env.get("BENTRAY_API_KEYS_FILE", "").strip()
        if key_file:
            try:
                text = Path(key_file).read_text(encoding="utf-8")
            except (OSError, UnicodeDecodeError) as exc:
                raise SettingsError(f"BENTRAY_API_KEYS_FILE: cannot read {key_file}: {exc}") from None
            keys += [line.strip() for line in text.splitlines() if line.strip() and not line.startswith("#")]
        if keys:
            values["api_keys"] = tuple(dict.fromkeys(keys))
        names = {
            "BENTRAY_DATA_DIR": "data_dir",
            "BENTRAY_MAX_RAYS": "max_rays",
            "BENTRAY_MAX_FIELD_POINTS": "max_field_points",
            "BENTRAY_MAX_UPLOAD_BYTES": "max_upload_bytes",
            "BENTRAY_MAX_QUEUE": "max_queue",
            "BENTRAY_MAX_JOB_SECONDS": "max_job_seconds",
            "BENTRAY_RETENTION_DAYS": "retention_days",
            "BENTRAY_WORKERS": "workers",
            "BENTRAY_MAX_JOB_MEMORY_BYTES": "max_job_memory_bytes",
            "BENTRAY_MAX_FIELD_DEPOSITS": "max_field_deposits",
            "BENTRAY_MAX_RAY_STEPS": "max_ray_steps",
            "BENTRAY_MAX_MESH_SECONDS": "max_mesh_seconds",
            "BENTRAY_VALIDATION_SECONDS": "validation_seconds",
            "BENTRAY_RETRY_AFTER_SECONDS": "retry_after_seconds",
            "BENTRAY_DASK_SCHEDULER": "dask_scheduler",
        }
        for var, field in names.items():
            raw = env.get(var, "").strip()
            if raw:
                values[field] = raw
        values.update({k: v for k, v in overrides.items() if v is not None})
        try:
            settings = cls.model_validate(values)
        except ValidationError as exc:
            lines = []
            reverse = {f: v for v, f in names.items()} | {"api_keys": "BENTRAY_API_KEYS"}
            for err in exc.errors(include_url=False):
                field = str(err["loc"][0]) if err["loc"] else "settings"
                lines.append(f"{reverse.get(field, field)}: {err['msg']}")
            raise SettingsError("invalid service settings:\n" + "\n".join(lines)) from None
        return settings.model_copy(update={"data_dir": settings.data_dir.absolute()})


def check_bind_host(settings: Settings, host: str) -> None:
    """Refuse a non-loopback bind address when no API key is configured (single local user)."""
    if settings.api_keys:
        return
    if host == "localhost":
        return
    try:
        loopback = ipaddress.ip_address(host).is_loopback
    except ValueError:
        loopback = False
    if not loopback:
        raise SettingsError(
            f"no API key configured (BENTRAY_API_KEYS or BENTRAY_API_KEYS_FILE): the single-user server binds "
            f"127.0.0.1 only, not {host!r}"
        )
