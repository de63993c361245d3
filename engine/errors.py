"""Typed engine errors. The service maps them to HTTP codes in one place (service/errors.py)."""

from __future__ import annotations


class BentrayError(Exception):
    """Base of every error bentray raises on purpose."""


class JobInputError(BentrayError, ValueError):
    """The job is valid JSON and schema but cannot run as asked (e.g. a source outside the mesh)."""


class MeshBuildError(BentrayError):
    """The media mesh could not be built within the limits (too many points, degenerate cells)."""


class MaterialTableError(BentrayError, ValueError):
    """A field's ground-reflection table has fewer materials (or bands) than the trace would index: the
    mesh's faces carry a material index the table lacks. Raised before any kernel runs."""
