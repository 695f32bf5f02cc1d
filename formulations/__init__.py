"""Measurement models and optimisation problems of attopt.

Each problem of the papers (``docs/references.md``) is written here once; ``solvers`` consume it.
Frames, quaternion order and the attitude direction are fixed in
``attopt.formulations.conventions`` (documented in ``docs/conventions.md``).
"""
