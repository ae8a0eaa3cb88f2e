"""Pendulum drop tests on a bench, real or simulated (docs/drops.md)."""
