"""Numerical ray-integration baselines (Euler, RK4, Dormand-Prince) the analytic tracer is measured against."""
