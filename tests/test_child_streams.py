"""Every child stream of a trial's seed is used by one part of the simulation only."""

from __future__ import annotations

from attopt.experiments import simulation
from attopt.experiments.adsb_snr import experiment, sky, spoofing


def test_child_streams_are_distinct() -> None:
    streams = {
        "gyro": simulation.GYRO_STREAM,
        "power offsets": experiment.OFFSET_STREAM,
        "spoofer": spoofing.SPOOFER_STREAM,
        "transmitters": sky.TRANSMITTER_STREAM,
        "messages": sky.MESSAGE_STREAM,
        "receiver chain": sky.CHAIN_STREAM,
    }
    assert len(set(streams.values())) == len(streams), streams
