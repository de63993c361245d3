"""The beams' smooth-medium switch (tracer.trace(smooth_beams=...), docs/physics.md §11).

Oracle: the tracer itself, three ways on the same rays and beam field (a coherent line of points in the
A-LD log profile over rigid ground, slab mesh): smooth_beams=False with the template's Hessians attached
must be bit for bit the trace without them (the exact mesh kicks), and the default must differ from it where
the medium curves (the smooth medium is in use) while the rays' final states stay bit for bit the same.
Measured: the smooth medium moves the 113 points' levels by 0.065 dB median, 0.53 dB at most.
"""

from __future__ import annotations

import numpy as np

import bentray  # noqa: F401
from bentray.engine import beam_field
from bentray.engine.media import build_media
from bentray.engine.mesh.hessian import hessian_of
from bentray.engine.tracer import trace
from bentray.scenes.field_models import FieldSpec
from bentray.scenes.profile_models import profile_from_spec
from bentray.scenes.schema import Job

LO = np.array([-20.0, -20.0, 0.0])
HI = np.array([620.0, 20.0, 150.0])
SRC = np.array([0.0, 0.0, 2.0])


def _trace(smooth: bool, with_hessian: bool):
    job = Job.model_validate(
        {
            "name": "smooth-switch",
            "scene": {"domain": {"min": LO.tolist(), "max": HI.tolist()}, "ground": {"kind": "flat"}},
            "profile": {"kind": "log", "c0": 340.0, "b": 1.0, "z_g": 1.0},
            "sources": [{"position": SRC.tolist()}],
            "rays": {"elevation_deg": {"min": -5, "max": 5, "count": 3}, "max_time_s": 1.7, "max_reflections": 6},
            "solver": {"curve": "parabolic", "representation": "slabs"},
            "outputs": ["report"],
        }
    )
    profile = profile_from_spec(job.profile)
    media = build_media(profile, "parabolic", job.solver, LO, HI, ground="reflect", top=job.scene.top.kind)
    el = np.linspace(-6.0, 6.0, 121)
    dirs = np.column_stack([np.cos(np.radians(el)), np.zeros_like(el), np.sin(np.radians(el))])
    spec = FieldSpec.model_validate(
        {
            "origin": [20.0, 0.0, 1.5],
            "spacing": [5.0, 1.0, 1.0],
            "shape": [116, 1, 1],
            "frequencies_hz": [250.0],
            "mode": "coherent",
            "absorption": False,
        }  # fmt: skip
    )
    template = beam_field.prepare(
        spec,
        elevation_deg=el,
        azimuth_deg=np.array([0.0]),
        n_rays=el.size,
        source_index=np.zeros(el.size, int),
        source_powers_w=None,
        materials=[None],
        max_reflections=6,
        c_ref=profile.c_ref,
        ground_sound_speed=340.0,
        n_face_materials=1,
    )
    if with_hessian:
        template.tables = template.tables._replace(hessian=hessian_of(media.mesh))
    buffers = template.like(template.weights, n_slots=1)
    cells = media.locate(SRC[None])
    res = trace(
        media.mesh,
        "parabolic",
        profile.c_ref,
        np.repeat(SRC[None], el.size, axis=0),
        dirs,
        np.full(el.size, cells[0]),
        max_time_s=1.7,
        max_reflections=6,
        field=buffers,
        smooth_beams=smooth,
    )
    return res, buffers.collapse().collapsed


def test_smooth_beams_false_ignores_the_templates_hessians_and_the_default_uses_them():
    exact, f_exact = _trace(smooth=False, with_hessian=False)
    off, f_off = _trace(smooth=False, with_hessian=True)
    on, f_on = _trace(smooth=True, with_hessian=True)
    np.testing.assert_array_equal(f_off.p, f_exact.p)
    np.testing.assert_array_equal(f_off.weight, f_exact.weight)
    np.testing.assert_array_equal(on.position, exact.position)  # the rays are the same
    assert f_on.p is not None and f_exact.p is not None
    lit = (np.abs(f_on.p[0]) > 0.0) & (np.abs(f_exact.p[0]) > 0.0)
    assert lit.sum() > 100
    moved = np.abs(20.0 * np.log10(np.abs(f_on.p[0][lit]) / np.abs(f_exact.p[0][lit])))
    assert 0.01 < float(np.median(moved)) < 0.5, moved  # in use, and a refinement, not a different field
