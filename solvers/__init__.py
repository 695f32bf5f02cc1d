"""Solvers of the problems in ``formulations``."""
