"""HTTP service (FastAPI) over the engine.

Not built yet: tracked by issue 6 (the HTTP service, the Python client and the CLI for scripted
studies). Nothing here is importable as an API today.
"""
