"""Numba kernels: pure functions over arrays (no I/O, no Python objects)."""
