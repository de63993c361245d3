"""The analytic traversal on CUDA (numba-cuda, the optional ``gpu`` extra) and the device choice."""
