"""The `adsb-snr` experiment: scenario, trial and report."""
