"""Meteorological conditions and emission periods inside one job (CNOSSOS-EU style long-term levels).

A job may list ``conditions``: each a sound-speed profile (and optionally a wind) with its occurrence in
the day, evening and night periods, as CNOSSOS-EU weighs favourable and homogeneous conditions
(Directive (EU) 2015/996, Annex II section 2.5.5). bentray runs the job once per condition and combines the
A-weighted levels in energy:

    L_period(x) = 10 lg( sum_c occ_(c, period) sum_g 10^((L_(c, g)(x) + o_(g, period)) / 10) ),
    Lden = 10 lg( (t_d 10^(L_day/10) + t_e 10^((L_evening + 5)/10) + t_n 10^((L_night + 10)/10)) / 24 ),

g the emission groups (sources with the same per-period offsets ``Source.period_offsets_db``, default 0
dB in every period), t the period lengths (``periods.hours``, default 12 / 4 / 8 h) and the penalties
``periods.penalties_db`` (default 0 / 5 / 10 dB). Occurrences of one period must sum to 1 over the
conditions.

Example::

    "conditions": [
      {"name": "favourable", "profile": {"kind": "log", "c0": 340, "b": 1, "z_g": 0.1},
       "occurrence": {"day": 0.5, "evening": 0.75, "night": 1.0}},
      {"name": "homogeneous", "profile": {"kind": "homogeneous", "c0": 340},
       "occurrence": {"day": 0.5, "evening": 0.25, "night": 0.0}}
    ]
"""

from __future__ import annotations

import json
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from bentray.scenes.profile_models import ProfileSpec
from bentray.scenes.wind_models import WindSpec

__all__ = [
    "MAX_CONDITIONS",
    "MAX_EMISSION_GROUPS",
    "PERIODS",
    "Condition",
    "Occurrence",
    "PeriodOffsets",
    "Periods",
    "condition_job",
    "medium_key",
    "occurrence_errors",
]

MAX_CONDITIONS = 8  # each condition is a full run of the job: the cost model multiplies by this count
MAX_EMISSION_GROUPS = 8  # distinct per-period offsets: each group's levels are held apart until combined
PERIODS = ("day", "evening", "night")
_SHARE_TOL = 1e-9  # occurrences of one period sum to 1 within this (rounding of decimal shares)
_NAME_RE = r"^[A-Za-z0-9_-]{1,40}$"  # becomes part of array and column names (spl_a__<name>)


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class Occurrence(_Model):
    """Share (0..1) of each period during which the condition holds."""

    day: float = Field(ge=0.0, le=1.0)
    evening: float = Field(ge=0.0, le=1.0)
    night: float = Field(ge=0.0, le=1.0)

    def share(self, period: str) -> float:
        return float(getattr(self, period))


class Condition(_Model):
    """One meteorological condition: its profile, its wind ("none": no wind; omitted: the job's wind)
    and its occurrence per period."""

    name: str = Field(pattern=_NAME_RE)
    profile: ProfileSpec | None = None  # None: the job's profile
    wind: WindSpec | Literal["none"] | None = None  # None: the job's wind; "none": calm
    occurrence: Occurrence


class PeriodOffsets(_Model):
    """A source's emission in each period relative to its ``power_db`` (dB, all bands; e.g. night traffic
    6 dB below the day's: ``{"day": 0, "evening": -2, "night": -6}``)."""

    day: float = Field(default=0.0, ge=-100.0, le=100.0)
    evening: float = Field(default=0.0, ge=-100.0, le=100.0)
    night: float = Field(default=0.0, ge=-100.0, le=100.0)

    def as_tuple(self) -> tuple[float, float, float]:
        return (self.day, self.evening, self.night)


class Periods(_Model):
    """Period lengths (hours, summing to 24) and penalties (dB) of Lden (Directive 2002/49/EC Annex I)."""

    hours: tuple[float, float, float] = (12.0, 4.0, 8.0)
    penalties_db: tuple[float, float, float] = (0.0, 5.0, 10.0)

    @model_validator(mode="after")
    def _day_of_24_hours(self) -> Periods:
        if any(not h > 0 for h in self.hours) or abs(sum(self.hours) - 24.0) > 1e-9:
            raise ValueError(f"hours must be > 0 and sum to 24 (day, evening, night); got {list(self.hours)}")
        if any(not -50.0 <= p <= 50.0 for p in self.penalties_db):
            raise ValueError(f"penalties_db must lie in -50..50 dB; got {list(self.penalties_db)}")
        return self


def occurrence_errors(conditions: list[Condition]) -> list[tuple[tuple[str | int, ...], str, Any]]:
    """(location, message, value) for unique names and occurrences that sum to 1 in every period."""
    errors: list[tuple[tuple[str | int, ...], str, Any]] = []
    seen: set[str] = set()
    for i, cond in enumerate(conditions):
        if cond.name in seen:
            errors.append((("conditions", i, "name"), f"condition name {cond.name!r} is used twice", cond.name))
        seen.add(cond.name)
    for period in PERIODS:
        shares = [c.occurrence.share(period) for c in conditions]
        total = sum(shares)
        if abs(total - 1.0) > _SHARE_TOL:
            errors.append(
                (
                    ("conditions",),
                    f"the {period} occurrences sum to {total:g} over the conditions "
                    f"({', '.join(f'{s:g}' for s in shares)}); they must sum to 1",
                    shares,
                )
            )
    return errors


def condition_job(job: Any, cond: Condition) -> Any:
    """The job under one condition: its profile and wind replaced as the condition says, no conditions."""
    update: dict[str, Any] = {"conditions": []}
    if cond.profile is not None:
        update["profile"] = cond.profile
    if cond.wind == "none":
        update["wind"] = None
    elif cond.wind is not None:
        update["wind"] = cond.wind
    return job.model_copy(update=update)


def medium_key(job: Any) -> str:
    """A key equal for jobs whose media (profile and wind) are the same: they can share one mesh."""
    wind = job.wind.model_dump(mode="json") if job.wind is not None else None
    return json.dumps([job.profile.model_dump(mode="json"), wind], sort_keys=True)
