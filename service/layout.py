"""Where the service keeps files under ``BENTRAY_DATA_DIR``, and the one check for user-given names.

    DATA/jobs.sqlite3                       the job store (WAL)
    DATA/jobs/<job id>/inputs/<name>        files a job reads (uploaded with it or copied from assets)
    DATA/jobs/<job id>/results/<file>       its outputs (names from engine.writers.OUTPUT_FILES)
    DATA/assets/<owner>/<name>              uploaded assets, per API key

Every name that comes from a request passes :func:`check_name` first: no separators, no ``..``,
no leading dot, a short ASCII alphabet, so a path joined from it can never leave its folder.
"""

from __future__ import annotations

import re
import shutil
from dataclasses import dataclass
from pathlib import Path

__all__ = ["JOB_ID_RE", "DataLayout", "check_name", "file_name_problem"]

JOB_ID_RE = re.compile(r"^[0-9a-f]{32}$")
_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,99}$")


def file_name_problem(name: str) -> str | None:
    """Why ``name`` is not acceptable as a plain file name, or None."""
    if not name:
        return "the file name is empty"
    if "/" in name or "\\" in name:
        return f"{name!r} contains a path separator; give a plain file name"
    if ".." in name:
        return f"{name!r} contains '..'; give a plain file name"
    if not _NAME_RE.match(name):
        return (
            f"{name!r} is not a plain file name: use letters, digits, '.', '_' and '-' "
            "(at most 100 characters, not starting with a dot)"
        )
    return None


def check_name(name: str) -> str:
    """Return ``name`` or raise ValueError with :func:`file_name_problem`'s reason."""
    problem = file_name_problem(name)
    if problem is not None:
        raise ValueError(problem)
    return name


@dataclass(frozen=True)
class DataLayout:
    root: Path

    def job_dir(self, job_id: str) -> Path:
        if not JOB_ID_RE.match(job_id):
            raise ValueError(f"not a job id: {job_id!r}")
        return self.root / "jobs" / job_id

    def inputs(self, job_id: str) -> Path:
        return self.job_dir(job_id) / "inputs"

    def results(self, job_id: str) -> Path:
        return self.job_dir(job_id) / "results"

    def asset_dir(self, owner: str) -> Path:
        return self.root / "assets" / check_name(owner)

    def asset_path(self, owner: str, name: str) -> Path:
        return self.asset_dir(owner) / check_name(name)

    def remove_job_files(self, job_id: str) -> None:
        shutil.rmtree(self.job_dir(job_id), ignore_errors=True)
