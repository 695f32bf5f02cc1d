"""The `wahba-mag-sun` experiment: scenario, trial and report."""
