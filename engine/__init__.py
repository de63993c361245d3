"""bentray engine: media profiles, media meshes, analytic ray-curve kernels, orchestration."""
