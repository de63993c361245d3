"""Typed engine errors. The service maps them to HTTP codes in one place (service/errors.py)."""

from __future__ import annotations


class BentrayError(Exception):
    """Base of every error bentray raises on purpose."""


class JobInputError(BentrayError, ValueError):
    """The job is valid JSON and schema but cannot run as asked (e.g. a source outside the mesh)."""


class MeshBuildError(BentrayError):
    """The media mesh could not be built within the limits (too many points, degenerate cells)."""
