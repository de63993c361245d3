"""Sound propagation physics outside the ray kernels: absorption, ground impedance, weighting."""
