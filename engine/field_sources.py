"""What produced each level: integer codes per field point / receiver, and the one function that merges
model contributions (diffraction, later the refractive-shadow model) into the beam field's arrays.

Codes (uint8, written as ``field_source`` into field.vti and receivers.csv; counted in report.json):

====  ==================  ====================================================================
 0    NONE                inside the ground or a building (``inside_solid`` = 1), or no level
 1    GEOMETRIC           the beam field alone (paraxial rays)
 2    DIFFRACTED          an edge-diffraction model alone (the beam field replaced)
 3    REFRACTIVE_SHADOW   a refractive-shadow model (creeping waves / turbulent scattering)
 4    COMBINATION         more than one of the above contribute (a blend or an added part)
 5    WAVE                the wave field (wavenumber integral, engine/wave_stage.py) in every band
====  ==================  ====================================================================

The combine API (:func:`combine`): the beam field's level arrays (``tl_<band>hz``, ``spl_<band>hz``,
``spl_a``, ``p_re_<band>hz`` / ``p_im_<band>hz``, flattened (V,) per band, as :func:`bentray.engine.beam_field.finalize`
writes them) plus a list of :class:`Contribution` s, applied in order. Each contribution brings, per band
and point, its own relative intensity ``rel`` (re the 1 m free-field intensity of a unit source, the
quantity behind ``tl``), optionally ``powered`` (W/m^2 with the sources' powers, behind ``spl``) and
complex pressure ``p`` (coherent maps), a ``weight`` (F, V) in [0, 1] and its ``code``:

- ``mode="replace"``: the field becomes ``(1 - w) field + w contribution`` (w = 1: the contribution
  alone; 0: untouched; between: a blend, continuous where w is); the diffraction model uses this in the
  shadow (w = 1) and across a lit-side transition zone.
- ``mode="add"``: the field becomes ``field + w contribution`` (energies add, pressures add when both are
  coherent): e.g. turbulent scattering added in a refractive shadow.

A second kind (code 3) is one more ``Contribution(code=REFRACTIVE_SHADOW, ...)`` in the list. The codes
follow from the weights: a point with w = 1 of a replacing contribution takes its code; a point where a
contribution and an earlier level both remain (0 < w < 1, or "add" onto a level) becomes COMBINATION.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

__all__ = [
    "COMBINATION",
    "DIFFRACTED",
    "GEOMETRIC",
    "NONE",
    "REFRACTIVE_SHADOW",
    "SOURCE_NAMES",
    "WAVE",
    "Contribution",
    "combine",
    "combine_receiver_rows",
    "counts",
]

NONE = 0
GEOMETRIC = 1
DIFFRACTED = 2
REFRACTIVE_SHADOW = 3
COMBINATION = 4
WAVE = 5
SOURCE_NAMES = {NONE: "none", GEOMETRIC: "geometric", DIFFRACTED: "diffracted",
                REFRACTIVE_SHADOW: "refractive_shadow", COMBINATION: "combination", WAVE: "wave"}  # fmt: skip
P_REF_INTENSITY = 1e-12  # W/m^2

FIELD_SOURCE_TEXT = (
    "field_source per point: 0 inside the ground or a building (or no level), 1 geometric (beams), "
    "2 diffracted (edge diffraction), 3 refractive shadow (creeping wave / turbulent scattering), "
    "4 combination, 5 wave field (wavenumber integral, every band); "
    "inside_solid: 1 where the point lies inside the ground or a building. "
    "NaN levels only inside solids (inside_solid = 1) or where no model reaches a point (field_source 0)"
)


@dataclass
class Contribution:
    """One model's levels on the field points (see the module docstring). rel, weight (F, V); powered
    (F, V) or None; p (F, V) complex or None; code one of the codes; mode "replace" or "add"."""

    code: int
    rel: np.ndarray
    weight: np.ndarray
    powered: np.ndarray | None = None
    p: np.ndarray | None = None
    mode: Literal["replace", "add"] = "replace"
    weight_powered: np.ndarray | None = None  # (F, V) weight for `powered` (default: weight)


def _lin(level_db: np.ndarray) -> np.ndarray:
    return np.where(np.isfinite(level_db), 10.0 ** (level_db / 10.0), 0.0)


def _db(x: np.ndarray) -> np.ndarray:
    out = np.full(x.shape, np.nan)
    pos = x > 0
    out[pos] = 10.0 * np.log10(x[pos])
    return out


def _merge(old: np.ndarray, new: np.ndarray, w: np.ndarray, mode: str) -> np.ndarray:
    return old + w * new if mode == "add" else (1.0 - w) * old + w * new


def combine(
    arrays: dict[str, np.ndarray],
    labels: list[str],
    a_weights_db: np.ndarray,
    contributions: list[Contribution],
    coherent: bool,
    inside_solid: np.ndarray | None = None,
) -> np.ndarray:
    """Apply contributions to the field arrays in place; returns the field_source codes (V,) uint8.

    arrays : name -> (V,) (or any shape with V points, reshaped back) as beam_field.finalize writes them;
    labels : the band labels (``tl_<label>hz``); a_weights_db (F,) A-weighting per band (for spl_a);
    coherent : the map's TL is |p|^2 (p arrays present) rather than an energy sum; inside_solid (V,) bool:
    those points get NaN levels and code 0 whatever the contributions say."""
    first = arrays[f"tl_{labels[0]}hz"]
    shape = first.shape
    n_pts = first.size
    rel = np.stack([_lin(-arrays[f"tl_{lab}hz"].reshape(-1)) for lab in labels])
    has_spl = f"spl_{labels[0]}hz" in arrays
    powered = (
        np.stack([_lin(arrays[f"spl_{lab}hz"].reshape(-1)) * P_REF_INTENSITY for lab in labels]) if has_spl else None
    )
    has_p = f"p_re_{labels[0]}hz" in arrays
    p = (
        np.stack([arrays[f"p_re_{lab}hz"].reshape(-1) + 1j * arrays[f"p_im_{lab}hz"].reshape(-1) for lab in labels])
        if has_p
        else None
    )
    p = np.where(np.isfinite(p), p, 0.0) if p is not None else None
    code = np.where(rel.max(axis=0) > 0, GEOMETRIC, NONE).astype(np.uint8)
    for c in contributions:
        w = np.clip(np.asarray(c.weight, float), 0.0, 1.0)
        touched = w.max(axis=0) > 0
        had = rel.max(axis=0) > 0
        rel = _merge(rel, c.rel, w, c.mode)
        if powered is not None and c.powered is not None:
            wp = np.clip(c.weight_powered, 0.0, 1.0) if c.weight_powered is not None else w
            powered = _merge(powered, c.powered, wp, c.mode)
        if p is not None and c.p is not None:
            p = _merge(p, c.p, w, c.mode)
            if coherent:
                rel = np.abs(p) ** 2
        full = (w.min(axis=0) >= 1.0) & (c.mode == "replace")
        code = np.where(touched & full, c.code, np.where(touched & had, COMBINATION, np.where(touched, c.code, code)))
        code = code.astype(np.uint8)
    if inside_solid is not None:
        solid = np.asarray(inside_solid, bool).reshape(-1)
        rel[:, solid] = 0.0
        if powered is not None:
            powered[:, solid] = 0.0
        if p is not None:
            p[:, solid] = np.nan
        code[solid] = NONE
    code[rel.max(axis=0) <= 0] = NONE
    for f, lab in enumerate(labels):
        arrays[f"tl_{lab}hz"] = -_db(rel[f]).reshape(shape)
        if p is not None:
            arrays[f"p_re_{lab}hz"] = p[f].real.reshape(shape)
            arrays[f"p_im_{lab}hz"] = p[f].imag.reshape(shape)
    if powered is not None:
        spl = _db(powered / P_REF_INTENSITY)
        for f, lab in enumerate(labels):
            arrays[f"spl_{lab}hz"] = spl[f].reshape(shape)
        lin = np.where(np.isfinite(spl), 10.0 ** ((spl + np.asarray(a_weights_db, float)[:, None]) / 10.0), 0.0)
        arrays["spl_a"] = _db(lin.sum(axis=0)).reshape(shape)
    assert code.size == n_pts
    return code


def combine_receiver_rows(
    rows: list[dict],
    labels: list[str],
    a_weights_db: np.ndarray,
    contributions_coh: list[Contribution],
    contributions_inc: list[Contribution],
) -> np.ndarray:
    """The same for receivers.csv rows (tl_coh_/tl_inc_/spl_coh_/spl_inc_/spl_a_coh/spl_a_inc columns):
    coherent columns with ``contributions_coh``, incoherent with ``contributions_inc``; sets each row's
    ``field_source`` (the incoherent one's code, or COMBINATION when they differ) and returns the codes."""
    codes = []
    for kind, contribs in (("coh", contributions_coh), ("inc", contributions_inc)):
        arrays = {f"tl_{lab}hz": np.array([r[f"tl_{kind}_{lab}hz"] for r in rows], float) for lab in labels}
        if rows and f"spl_{kind}_{labels[0]}hz" in rows[0]:
            for lab in labels:
                arrays[f"spl_{lab}hz"] = np.array([r[f"spl_{kind}_{lab}hz"] for r in rows], float)
        codes.append(combine(arrays, labels, a_weights_db, contribs, coherent=False))
        for i, r in enumerate(rows):
            for lab in labels:
                r[f"tl_{kind}_{lab}hz"] = float(arrays[f"tl_{lab}hz"][i])
                if f"spl_{lab}hz" in arrays:
                    r[f"spl_{kind}_{lab}hz"] = float(arrays[f"spl_{lab}hz"][i])
            if "spl_a" in arrays:
                r[f"spl_a_{kind}"] = float(arrays["spl_a"][i])
    code = np.where(codes[0] == codes[1], codes[1], COMBINATION).astype(np.uint8)
    for i, r in enumerate(rows):
        r["field_source"] = int(code[i])
    return code


def counts(code: np.ndarray, inside_solid: np.ndarray | None = None) -> dict[str, int]:
    """Points per field_source name (and ``inside_solid``), for the report."""
    out = {name: int(np.count_nonzero(code == k)) for k, name in SOURCE_NAMES.items()}
    if inside_solid is not None:
        out["inside_solid"] = int(np.count_nonzero(inside_solid))
    return out
