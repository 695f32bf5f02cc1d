"""The `geo-snr-stations` experiment: scenario, trial and report."""
