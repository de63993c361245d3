"""Job-file schema of the optional ``wind`` key (pydantic v2) and the bridge to the engine's wind fields.

A wind is a JSON object beside ``profile`` with a ``kind`` discriminator, e.g. ``{"kind": "log",
"u_star": 0.5, "z_g": 0.1, "direction_deg": 0}``; it combines with any profile through the effective
sound speed ``c_eff = c + u . e`` per ray azimuth (docs/physics.md §7, engine/wind.py). Units: metres,
m/s, degrees. ``direction_deg`` is the direction the wind blows TOWARD, counter-clockwise from +x
(0: toward +x, so rays launched along +x travel downwind). Validators only check; unknown keys and
NaN/inf are rejected.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, model_validator

from bentray.engine.wind import DEFAULT_Z_REF_M, MAX_U_STAR, wind_spec
from bentray.scenes.bounds import MAX_COORD_M, Coord

__all__ = ["LogWindSpec", "RidgeWindSpec", "WindSpec", "WIND_SPEC_ADAPTER", "wind_from_spec"]


class _WindSpecBase(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    u_star: float = Field(gt=0.0, le=MAX_U_STAR, description="Friction velocity u* (m/s); u = (u*/0.41) ln(z/z_g).")
    z_g: float = Field(
        gt=0.0, le=MAX_COORD_M, description="Roughness length z_g (m); no wind at or below z_g above the surface."
    )
    direction_deg: float = Field(
        ge=-3600.0, le=3600.0, description="Direction the wind blows toward (degrees, counter-clockwise from +x)."
    )
    ground_z_m: Coord = Field(0.0, description="Height of the flat ground (ridge: its foot) the wind starts from (m).")


class LogWindSpec(_WindSpecBase):
    """Log law over flat ground: |u| = (u*/K) ln((z - ground_z)/z_g) above z_g, 0 below (K = 0.41)."""

    kind: Literal["log"] = "log"


class RidgeWindSpec(_WindSpecBase):
    """A-UW / A-DW: log law above the ridge h(x) = H L^2/((x - crest_x)^2 + L^2) plus the potential-flow
    speed-up du = u_ref H L ((dz + L)^2 - X^2) / (X^2 + (dz + L)^2)^2, u_ref = the log-law speed at z_ref_m;
    the ridge axis runs along y. Below z_g above the surface the speed falls linearly to 0."""

    kind: Literal["ridge"] = "ridge"
    height_m: float = Field(ge=0.0, le=MAX_COORD_M, description="Ridge height H (m).")
    half_width_m: float = Field(
        gt=0.0, le=MAX_COORD_M, description="Ridge half-width L (m): the height is H/2 at |x - crest_x| = L."
    )
    crest_x_m: Coord = Field(0.0, description="x of the crest line (m).")
    z_ref_m: float = Field(
        DEFAULT_Z_REF_M, gt=0.0, le=MAX_COORD_M, description="Reference height of u_ref above the surface (m)."
    )

    @model_validator(mode="after")
    def _z_ref_above_z_g(self) -> RidgeWindSpec:
        if not self.z_ref_m > self.z_g:
            raise ValueError(f"z_ref_m ({self.z_ref_m}) must be above z_g ({self.z_g})")
        return self


WindSpec = Annotated[LogWindSpec | RidgeWindSpec, Field(discriminator="kind")]

WIND_SPEC_ADAPTER: TypeAdapter[Any] = TypeAdapter(WindSpec)


def wind_from_spec(spec: Any) -> tuple[int, np.ndarray]:
    """Kernel form (code, float64 params) of a validated spec model, or of a plain dict (validated here)."""
    if isinstance(spec, dict):
        spec = WIND_SPEC_ADAPTER.validate_python(spec)
    if not isinstance(spec, _WindSpecBase):
        raise TypeError(f"expected a wind spec model or dict, got {type(spec).__name__}")
    params = spec.model_dump()
    kind = str(params.pop("kind"))  # every concrete spec has its Literal kind (the base declares none)
    return wind_spec(kind, params)
