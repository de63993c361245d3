"""HTTP service (FastAPI) over the engine: job store (SQLite WAL), job processes, routes under /v1.

Modules: settings (environment, limits), errors (typed errors -> HTTP codes), store (the queue),
layout (files under the data folder), uploads (checks of scene files), worker (job processes and
their supervisor), models (API response types), app (routes, ``create_app``), server (``serve``).
Import :mod:`bentray.service.app` only where FastAPI is installed (``bentray[service]``).
"""
