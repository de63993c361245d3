"""Job-file schema of the optional ``turbulence`` key (pydantic v2): the strength of the atmospheric
turbulence that scatters sound into refractive shadows (docs/physics.md, "Refractive shadows").

    "turbulence": {"c_t2": 0.008, "c_v2": 0.12}

``c_t2`` is the structure parameter of temperature fluctuations C_T^2 (K^2 m^-2/3), ``c_v2`` that of
wind-velocity fluctuations C_v^2 (m^4/3 s^-2); the key is absent (off) by default. Typical values near
the ground (a few metres up), as the engineering methods use them:

| condition | C_T^2 (K^2 m^-2/3) | C_v^2 (m^4/3 s^-2) |
| --- | --- | --- |
| weak (calm night, overcast) | 0.001 | 0.01 |
| moderate (the Nord2000 default) | 0.008 | 0.12 |
| strong (sunny afternoon, wind) | 0.1 | 1.0 |

The moderate pair is Nord2000's default (Plovsing, "Nord2000. Comprehensive outdoor sound propagation
model", DELTA AV 1849/00 and the Nordtest proposal AV 1106/07; the Danish EPA's Nord2000 test cases,
Environmental Project 1022, 2005, use it); the weak and strong rows bracket the daytime surface-layer
range of Ostashev and Wilson ("Acoustics in moving inhomogeneous media", 2nd ed. 2015, ch. 6) and of
Wilson's measurements (C_v^2 up to ~1, C_T^2 up to ~0.1-1 near noon). Values are refused outside
[0, MAX_C_T2] and [0, MAX_C_V2]: the largest surface-layer values reported are about an order of
magnitude below these bounds, so a value beyond them is a unit mistake (e.g. C_n^2 of optics, or
K^2 per m instead of m^-2/3), not weather. Unknown keys and NaN/inf are refused.
"""

from __future__ import annotations

import math

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

__all__ = ["MAX_C_T2", "MAX_C_V2", "TURBULENCE_PRESETS", "TurbulenceSpec"]

MAX_C_T2 = 10.0  # K^2 m^-2/3
MAX_C_V2 = 10.0  # m^4/3 s^-2

TURBULENCE_PRESETS: dict[str, tuple[float, float]] = {  # (C_T^2, C_v^2), see the module docstring
    "weak": (0.001, 0.01),
    "moderate": (0.008, 0.12),
    "strong": (0.1, 1.0),
}


def _in_range(name: str, unit: str, top: float, typical: str, value: float) -> float:
    if not (math.isfinite(value) and 0.0 <= value <= top):
        raise ValueError(f"{name} must be in [0, {top:g}] {unit} (typical near the ground: {typical}), got {value!r}")
    return value


class TurbulenceSpec(BaseModel):
    """Turbulence strengths of the scattering into refractive shadows (both >= 0, not both 0)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=True)  # NaN/inf get the range message below

    c_t2: float = Field(
        description="C_T^2, structure parameter of temperature fluctuations (K^2 m^-2/3); typical 0.001-0.1."
    )
    c_v2: float = Field(
        description="C_v^2, structure parameter of wind-velocity fluctuations (m^4/3 s^-2); typical 0.01-1."
    )

    @field_validator("c_t2")
    @classmethod
    def _c_t2_range(cls, value: float) -> float:
        return _in_range("c_t2 (C_T^2)", "K^2 m^-2/3", MAX_C_T2, "0.001 weak, 0.008 moderate, 0.1 strong", value)

    @field_validator("c_v2")
    @classmethod
    def _c_v2_range(cls, value: float) -> float:
        return _in_range("c_v2 (C_v^2)", "m^4/3 s^-2", MAX_C_V2, "0.01 weak, 0.12 moderate, 1 strong", value)

    @model_validator(mode="after")
    def _not_both_zero(self) -> TurbulenceSpec:
        if self.c_t2 == 0.0 and self.c_v2 == 0.0:
            raise ValueError("c_t2 and c_v2 are both 0: leave the turbulence key out to switch scattering off")
        return self
