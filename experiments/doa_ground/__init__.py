"""The `doa-ground` experiment: scenario, trial and report."""
