"""Which device a trace runs on (``solver.device``): plain Python, importable without numba-cuda.

- ``cpu`` (default): the numba CPU kernels (engine/kernels/traverse.py).
- ``cuda``: the CUDA kernel (engine/gpu/kernel.py); a clear error naming ``solver.device`` when numba-cuda is
  not installed or no device is present. Under numba's CUDA simulator (``NUMBA_ENABLE_CUDASIM=1``) ``cuda``
  runs the same kernel in the simulator (tests).
- ``auto``: cuda when a real device is present (never the simulator) and the job has at least
  :data:`AUTO_MIN_RAYS` rays, else cpu.
"""

from __future__ import annotations

import os

from bentray.engine.errors import JobInputError

__all__ = ["AUTO_MIN_RAYS", "cuda_status", "resolve_device", "simulator_enabled"]

# auto: below this many rays the CUDA path does not pay. A first call in a process compiles the kernel (tens
# of seconds; numba caches nothing for CUDA here) and each job copies its mesh once (~0.1 ms per 10,000 cells);
# 100,000 rays is about 0.5-2 s of CPU tracing on 2-16 cores for the built-in scenes. Not yet measured on a device.
AUTO_MIN_RAYS = 100_000


def simulator_enabled() -> bool:
    """True when numba's CUDA simulator is switched on (``NUMBA_ENABLE_CUDASIM=1`` at import)."""
    return os.environ.get("NUMBA_ENABLE_CUDASIM", "0") not in ("", "0")


def cuda_status() -> tuple[bool, str]:
    """(usable, why): whether the CUDA kernel can run here (a device, or the simulator), and a sentence."""
    try:
        import numba_cuda  # noqa: F401  (the package, not numba's deprecated built-in target)
        from numba import cuda
    except ImportError as exc:  # numba-cuda (the gpu extra) missing
        return False, f"numba-cuda is not installed (pip install 'bentray[gpu]'): {exc}"
    if simulator_enabled():
        return True, "numba CUDA simulator (NUMBA_ENABLE_CUDASIM=1)"
    try:
        if cuda.is_available():
            dev = cuda.get_current_device()
            name = dev.name.decode() if isinstance(dev.name, bytes) else str(dev.name)
            return (
                True,
                f"CUDA device {name} (compute capability {dev.compute_capability[0]}.{dev.compute_capability[1]})",
            )
    except Exception as exc:  # driver present but broken: report, do not crash
        return False, f"no usable CUDA device ({type(exc).__name__}: {exc})"
    return False, "no CUDA device (numba.cuda.is_available() is False)"


def resolve_device(requested: str, n_rays: int) -> tuple[str, str]:
    """("cpu" | "cuda", reason) for ``solver.device`` and a job of ``n_rays`` rays; JobInputError naming
    ``solver.device`` when ``cuda`` is asked for and cannot run."""
    if requested == "cpu":
        return "cpu", "solver.device cpu"
    usable, why = cuda_status()
    if requested == "cuda":
        if not usable:
            raise JobInputError(f"solver.device: 'cuda' cannot run here: {why}")
        return "cuda", why
    if requested != "auto":
        raise JobInputError(f"solver.device: unknown device {requested!r}; expected cpu, cuda or auto")
    if not usable or simulator_enabled():
        return "cpu", f"auto: {why if not usable else 'the simulator is not a device'}"
    if n_rays < AUTO_MIN_RAYS:
        return "cpu", f"auto: {n_rays:,} rays < {AUTO_MIN_RAYS:,} (too few to pay for the device)"
    return "cuda", f"auto: {why}, {n_rays:,} rays"
