"""Start the service: ``serve`` (uvicorn with the embedded supervisor) and ``run_worker`` (supervisor only).

``bentray serve --host H --port P --workers N`` runs one uvicorn process (the API, async) and up to N
job processes (children of its supervisor thread). ``--workers 0`` runs the API alone; then
``python -m bentray.service worker`` (same ``BENTRAY_DATA_DIR``) runs the jobs, e.g. in its own container.
"""

from __future__ import annotations

import logging
from pathlib import Path

from bentray.service.settings import Settings, check_bind_host

__all__ = ["run_worker", "serve"]


def _settings(data_dir: str | Path | None, workers: int | None) -> Settings:
    return Settings.from_env(data_dir=Path(data_dir) if data_dir is not None else None, workers=workers)


def serve(
    host: str = "127.0.0.1",
    port: int = 8000,
    workers: int | None = None,
    data_dir: str | Path | None = None,
    log_level: str = "info",
) -> None:
    """Run the API (and, with workers > 0, the job processes) until interrupted.

    Raises :class:`bentray.service.settings.SettingsError` before listening when the settings are bad or
    when no API key is configured and ``host`` is not a loopback address.
    """
    import uvicorn

    from bentray.service.app import create_app

    settings = _settings(data_dir, workers)
    check_bind_host(settings, host)
    logging.basicConfig(level=log_level.upper(), format="%(asctime)s %(name)s %(levelname)s %(message)s")
    app = create_app(settings)
    uvicorn.run(app, host=host, port=port, log_level=log_level, workers=1, timeout_graceful_shutdown=5)


def run_worker(workers: int | None = None, data_dir: str | Path | None = None, log_level: str = "info") -> None:
    """Run a supervisor alone (no API) on the data folder until SIGTERM/SIGINT."""
    from bentray.service.worker import Supervisor

    settings = _settings(data_dir, workers)
    logging.basicConfig(level=log_level.upper(), format="%(asctime)s %(name)s %(levelname)s %(message)s")
    if settings.workers < 1:
        settings = settings.model_copy(update={"workers": 1})
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    Supervisor(settings).run_forever()
