"""The `adsb-sky` experiment: every ADS-B estimator under the paper's sky and the real one."""
