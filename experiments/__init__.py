"""Scenarios, the sweep runner, the CLI and the report of attopt."""
