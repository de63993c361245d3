"""The service's routes: one ``APIRouter`` per resource, included by :func:`bentray.service.app.create_app`."""

from fastapi import APIRouter

from bentray.service.routes.assets import router as assets
from bentray.service.routes.health import router as health
from bentray.service.routes.jobs import router as jobs
from bentray.service.routes.scenes import router as scenes

__all__ = ["ROUTERS"]

ROUTERS: tuple[APIRouter, ...] = (health, scenes, assets, jobs)
