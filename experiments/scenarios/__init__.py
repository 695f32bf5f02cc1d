"""Simulation scenarios: true geometry and simulated sensor measurements."""
