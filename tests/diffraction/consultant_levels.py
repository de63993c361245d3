"""Consultant case levels behind the buildings: not a test, the measurement behind test_consultant_full.py's
docstring (diffracted levels against homogeneous air and against the refractive-shadow stage's own level).

``PYTHONPATH=. python tests/diffraction/consultant_levels.py run upward UP.npz`` runs one condition with
hooks that keep the diffraction stage's field before the shadow merge and the shadow stage's energy;
``... compare UP.npz HOM.npz`` prints the comparison (points the diffraction stage models, code 2).
"""

from __future__ import annotations

import json
import resource
import sys
import time

import numpy as np


def run(cond: str, out_path: str) -> None:
    import bentray.engine.run as run_mod
    import bentray.engine.shadow_stage as ss
    from bentray.scenes.schema import Job
    from tests.diffraction.test_consultant_full import EXAMPLES

    keep: dict[str, np.ndarray] = {}
    stage = run_mod.stage_refractive_shadow
    energy = ss._shadow_energy

    def hooked_stage(job, profile, wind, surfaces, setup, field_arrays, receivers, log):  # noqa: ANN001, ANN202
        if field_arrays is not None:
            for lab in ("500", "1000"):
                keep[f"pre_tl_{lab}"] = np.array(field_arrays.arrays[f"tl_{lab}hz"], float).reshape(-1)
            keep["pre_code"] = np.array(field_arrays.arrays["field_source"]).reshape(-1)
        return stage(job, profile, wind, surfaces, setup, field_arrays, receivers, log)

    def hooked_energy(*args):  # noqa: ANN002, ANN202
        rel, powered, applies = energy(*args)
        if "sh_rel" not in keep:
            keep["sh_rel"], keep["sh_applies"] = rel.copy(), applies.copy()
        return rel, powered, applies

    run_mod.stage_refractive_shadow = hooked_stage
    ss._shadow_energy = hooked_energy
    spec = json.loads((EXAMPLES / f"consultant-{cond}.json").read_text())
    t0 = time.perf_counter()
    out = run_mod.run_job(Job.model_validate(spec), base_dir=EXAMPLES)
    wall = time.perf_counter() - t0
    a = out.field.arrays
    air = np.asarray(a["inside_solid"]).reshape(-1) == 0
    res = dict(keep)
    for lab in ("500", "1000"):
        res[f"tl_{lab}"] = np.asarray(a[f"tl_{lab}hz"], float).reshape(-1)
    res["code"], res["air"] = np.asarray(a["field_source"]).reshape(-1), air
    rows = out.receivers.rows
    with_level = sum(all(np.isfinite(r[f"tl_inc_{lab}hz"]) for lab in ("500", "1000")) for r in rows)
    np.savez(out_path, **res)
    stages = {k: round(float(v), 1) for k, v in out.report.get("timings_s", {}).items() if isinstance(v, float)}
    missing = {lab: int(np.count_nonzero(~np.isfinite(res[f"tl_{lab}"]) & air)) for lab in ("500", "1000")}
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6
    print(f"{cond}: wall {wall:.0f} s, peak RSS {rss:.2f} GB, stages {stages}")
    print(f"air points without a level {missing}; facades with a level {with_level} / {len(rows)}")


def compare(up_path: str, hom_path: str) -> None:
    u, h = np.load(up_path), np.load(hom_path)
    air = u["air"]
    n = air.size
    dif = (u["pre_code"] == 2) & air
    app = u["sh_applies"][:n]
    print(
        f"air points {air.sum()}; diffracted (diffraction stage code 2) {dif.sum()}, in the shadow {(dif & app).sum()}"
    )
    for k, lab in enumerate(("500", "1000")):
        pre, hom = -u[f"pre_tl_{lab}"], -h[f"tl_{lab}"]
        sh = 10 * np.log10(np.maximum(u["sh_rel"][k][:n], 1e-300))
        m = dif & np.isfinite(pre) & np.isfinite(hom)
        dd = pre[m] - hom[m]
        print(f"{lab} Hz: diffracted - homogeneous: median {np.median(dd):.1f} dB (p10 {np.percentile(dd, 10):.1f}, "
              f"p90 {np.percentile(dd, 90):.1f})")  # fmt: skip
        ma = m & app & (sh > -299)
        ds = pre[ma] - sh[ma]
        print(f"  {ma.sum()} in the shadow: diffracted - shadow stage: median {np.median(ds):.1f} dB (p10 "
              f"{np.percentile(ds, 10):.1f}, p90 {np.percentile(ds, 90):.1f}, max {ds.max():.1f}); shadow larger at "
              f"{np.count_nonzero(ds < 0)}")  # fmt: skip
    code = u["code"]
    print("final codes in the air:", {int(c): int(np.count_nonzero((code == c) & air)) for c in np.unique(code[air])})


if __name__ == "__main__":
    if sys.argv[1] == "run":
        run(sys.argv[2], sys.argv[3])
    else:
        compare(sys.argv[2], sys.argv[3])
