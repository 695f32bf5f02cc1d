"""The on-disk cache of the scenarios' geometry (experiments/environment/disk_cache.py).

Every test points ``ATTOPT_CACHE_DIR`` at its own ``tmp_path``.
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np
import pytest
from pydantic import BaseModel
from scipy.spatial.transform import Rotation

from attopt.experiments.adsb_snr.parameters import AdsbScenario, TrafficParameters
from attopt.experiments.adsb_snr.scenario import _build_adsb_geometry
from attopt.experiments.benchmarks import geometry as geometry_benchmark
from attopt.experiments.doa_ground.parameters import DoaScenario
from attopt.experiments.doa_ground.scenario import orbit_track
from attopt.experiments.environment import disk_cache
from attopt.experiments.environment.disk_cache import cache_directory, cache_key, disk_cached
from attopt.experiments.geo_snr_stations.parameters import GeoWorld
from attopt.experiments.geo_snr_stations.scenario import _build as build_geo
from attopt.experiments.wahba_mag_sun.experiment import WahbaMagSunParameters
from attopt.experiments.wahba_mag_sun.parameters import AttitudeProfile
from attopt.experiments.wahba_mag_sun.scenario import build_geometry as build_wahba

WAHBA = WahbaMagSunParameters()
DOA = DoaScenario()


def _wahba_arguments(duration_s: float = 1200.0, attitude: AttitudeProfile = WAHBA.attitude):
    """1200 s at 10 s: the window holds the start of the eclipse (at 1001 s)."""
    return (WAHBA.orbit, WAHBA.start_utc, duration_s, 10.0, attitude)


BUILDERS: dict[str, tuple[Callable[..., Any], tuple]] = {
    "wahba-mag-sun": (build_wahba, _wahba_arguments()),
    "adsb-snr": (
        _build_adsb_geometry,
        (
            AdsbScenario(
                duration_s=300.0, step_s=10.0, traffic=TrafficParameters(n_aircraft=200)
            ).key(),
        ),
    ),
    "geo-snr-stations": (
        build_geo,
        (GeoWorld(duration_s=600.0, step_s=60.0).model_dump_json(), True),
    ),
    "doa-ground": (orbit_track, (DOA.orbit.tle(), DOA.start_utc, 300.0, 10.0)),
}
"""Every disk-cached builder, with arguments of a short window."""


@dataclasses.dataclass(frozen=True)
class Toy:
    """A result holding every kind of value the entry format stores."""

    values: np.ndarray
    labels: np.ndarray
    flags: np.ndarray
    attitude: Rotation
    single: Rotation
    scale: np.float64
    count: int
    name: str
    missing: None
    pairs: tuple[tuple[float, float], ...]
    items: list[float]
    model: AttitudeProfile


class Counter:
    """A toy builder that counts its calls; results depend on ``size`` and ``scale``."""

    def __init__(self) -> None:
        self.calls = 0

    def __call__(self, size: int, scale: float = 1.0) -> Toy:
        self.calls += 1
        rng = np.random.default_rng(size)
        return Toy(
            values=scale * rng.standard_normal((size, 3)).T,  # not C-contiguous
            labels=np.array(["a", "bc", "def"][: min(size, 3)]),
            flags=rng.random(size) < 0.5,
            attitude=Rotation.random(size, rng=rng),
            single=Rotation.random(rng=rng),
            scale=np.float64(scale),
            count=size,
            name=f"toy {size}",
            missing=None,
            pairs=((0.1, float("nan")), (1.0 / 3.0, -0.0)),
            items=[0.1, 0.2],
            model=AttitudeProfile(pitch_amplitude_deg=scale),
        )


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("ATTOPT_CACHE_DIR", str(tmp_path))
    return tmp_path


@pytest.fixture
def counter() -> Counter:
    return Counter()


@pytest.fixture
def toy(counter):
    """``counter`` disk-cached, named like a module-level function of this module."""
    return disk_cached(_named(counter, "toy_builder"))


def _named(function: Callable[..., Any], qualname: str) -> Callable[..., Any]:
    """``function`` under the name ``qualname`` of this module, with its signature."""

    def named(*args: Any, **kwargs: Any) -> Any:
        return function(*args, **kwargs)

    named.__qualname__ = qualname
    named.__signature__ = inspect.signature(function)
    return named


def assert_identical(actual: Any, expected: Any, where: str = "result") -> None:
    """Equal value by value: arrays with ``np.array_equal`` and the same dtype and shape,
    rotations by their quaternions, dataclasses field by field, scalars of the same type."""
    assert type(actual) is type(expected), where
    if isinstance(expected, np.ndarray):
        assert actual.dtype == expected.dtype, where
        assert actual.shape == expected.shape, where
        assert np.array_equal(actual, expected, equal_nan=expected.dtype.kind in "fc"), where
    elif isinstance(expected, Rotation):
        assert actual.single == expected.single, where
        assert_identical(actual.as_quat(), expected.as_quat(), f"{where} (quaternions)")
    elif dataclasses.is_dataclass(expected):
        for field in dataclasses.fields(expected):
            name = f"{where}.{field.name}"
            assert_identical(getattr(actual, field.name), getattr(expected, field.name), name)
    elif isinstance(expected, tuple | list):
        assert len(actual) == len(expected), where
        for index, (a, e) in enumerate(zip(actual, expected, strict=True)):
            assert_identical(a, e, f"{where}[{index}]")
    elif isinstance(expected, float) and np.isnan(expected):
        assert np.isnan(actual), where
    elif isinstance(expected, BaseModel | int | float | str | np.generic) or expected is None:
        assert actual == expected, where
        if isinstance(expected, float):
            assert np.copysign(1.0, actual) == np.copysign(1.0, expected), where
    else:
        raise AssertionError(f"{where}: unexpected {type(expected).__name__}")


@pytest.mark.parametrize("scenario", list(BUILDERS))
def test_loaded_geometry_is_bit_identical_to_a_fresh_one(scenario, cache):
    builder, arguments = BUILDERS[scenario]
    build = inspect.unwrap(builder)  # the builder itself, neither cache in front
    calls = []

    @functools.wraps(build)
    def spy(*args: Any) -> Any:
        calls.append(args)
        return build(*args)

    fresh = build(*arguments)
    stored = builder.__wrapped__(*arguments)  # the scenario's own disk cache, without lru
    assert (cache / f"{cache_key(builder, *arguments)}.npz").is_file()
    loaded = disk_cached(spy)(*arguments)  # same name and arguments: the entry stored above
    assert calls == []
    assert_identical(stored, fresh)
    assert_identical(loaded, fresh)


def test_every_kind_of_value_round_trips(cache, counter, toy):
    fresh = counter(5, scale=2.0)
    assert_identical(toy(5, scale=2.0), fresh)
    assert_identical(toy(5, scale=2.0), fresh)
    assert counter.calls == 2  # the fresh one and the first cached call
    assert len(list(cache.glob("*.npz"))) == 1
    assert list(cache.glob(".*")) == []  # no temporary file left behind


def test_loaded_arrays_have_the_layout_of_built_ones(cache, toy):
    built = toy(4)
    loaded = toy(4)
    assert built.values.flags.c_contiguous and loaded.values.flags.c_contiguous
    assert built.values.flags.writeable and loaded.values.flags.writeable


def test_different_arguments_give_different_keys(toy):
    keys = {
        cache_key(toy, 5),
        cache_key(toy, 6),
        cache_key(toy, 5, scale=2.0),
        cache_key(toy, 5, scale=-0.0),
    }
    assert len(keys) == 4
    assert cache_key(toy, 5) == cache_key(toy, size=5) == cache_key(toy, 5, 1.0)
    wahba = {
        cache_key(build_wahba, *_wahba_arguments()),
        cache_key(build_wahba, *_wahba_arguments(duration_s=1200.5)),
        cache_key(build_wahba, *_wahba_arguments(attitude=AttitudeProfile(roll_amplitude_deg=3.5))),
    }
    assert len(wahba) == 3


def test_different_arguments_give_different_entries(cache, counter, toy):
    assert not np.array_equal(toy(5).values, toy(5, scale=2.0).values)
    assert counter.calls == 2
    toy(5)
    assert counter.calls == 2
    assert len(list(cache.glob("*.npz"))) == 2


@pytest.mark.parametrize("name", ["numpy", "astropy-iers-data", "attopt-source", "format"])
def test_a_version_change_gives_a_new_key(name, cache, counter, toy, monkeypatch):
    before = cache_key(toy, 5)
    toy(5)
    changed = {**disk_cache.environment(), name: "changed"}
    monkeypatch.setattr(disk_cache, "environment", lambda: changed)
    assert cache_key(toy, 5) != before
    toy(5)
    assert counter.calls == 2  # the old entry is not used
    assert [path.stem for path in cache.glob("*.npz")] == [cache_key(toy, 5)]  # nor kept


def test_the_source_digest_covers_every_package():
    versions = disk_cache.environment()
    assert versions["attopt"] and len(versions["attopt-source"]) == 64
    assert set(disk_cache.LIBRARIES) <= set(versions)
    assert "absent" not in versions.values()


@pytest.mark.parametrize(
    "damage",
    ["garbage", "empty", "truncated", "another key"],
)
def test_a_corrupt_entry_is_rebuilt_and_overwritten(damage, cache, counter, toy):
    expected = toy(5)
    (path,) = cache.glob("*.npz")
    content = path.read_bytes()
    if damage == "garbage":
        path.write_bytes(b"not an npz file")
    elif damage == "empty":
        path.write_bytes(b"")
    elif damage == "truncated":
        path.write_bytes(content[: len(content) // 2])
    else:
        np.savez(path, __key__=np.array("{}"), __structure__=np.array("null"))
    assert_identical(toy(5), expected)
    assert counter.calls == 2
    assert_identical(toy(5), expected)  # overwritten: loaded again
    assert counter.calls == 2


def test_concurrent_builds_of_one_entry_store_it_once(cache, counter):
    both_building = threading.Barrier(2)

    def slow(size: int) -> Toy:
        both_building.wait(timeout=30)  # neither has stored its entry yet
        return counter(size)

    builder = disk_cached(_named(slow, "slow_builder"))
    with ThreadPoolExecutor(2) as pool:
        first, second = pool.map(builder, [5, 5])
    assert counter.calls == 2
    assert_identical(first, second)
    assert [path.stem for path in cache.iterdir()] == [cache_key(builder, 5)]
    assert_identical(builder(5), first)
    assert counter.calls == 2


def test_disabled_cache_builds_every_time(tmp_path, monkeypatch, counter, toy):
    monkeypatch.setenv("ATTOPT_CACHE_DIR", "OFF")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.setenv("HOME", str(tmp_path))
    assert cache_directory() is None
    first, second = toy(5), toy(5)
    assert counter.calls == 2
    assert_identical(first, second)
    assert list(tmp_path.iterdir()) == []


def test_unusable_directory_falls_back_to_building(tmp_path, monkeypatch, counter, toy):
    blocker = tmp_path / "file"
    blocker.write_text("a file where the cache directory's parent should be")
    monkeypatch.setenv("ATTOPT_CACHE_DIR", str(blocker / "cache"))
    assert_identical(toy(5), counter(5))
    toy(5)
    assert counter.calls == 3


def test_default_directory(tmp_path, monkeypatch):
    monkeypatch.delenv("ATTOPT_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert cache_directory() == tmp_path / "attopt"
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path))
    assert cache_directory() == tmp_path / ".cache" / "attopt"


def test_the_suite_shares_one_cache_per_run(tmp_path_factory):
    """tests/conftest.py: the run's base temporary directory, whichever worker asks."""
    base = tmp_path_factory.getbasetemp()
    assert cache_directory() in (base / "attopt-cache", base.parent / "attopt-cache")


def test_results_the_format_cannot_hold_raise(cache):
    objects = disk_cached(_named(lambda: np.array([None, 1], dtype=object), "objects"))
    with pytest.raises(TypeError, match="Python objects"):
        objects()

    @dataclasses.dataclass(frozen=True)
    class Local:
        value: float

    local = disk_cached(_named(lambda: Local(1.0), "local"))
    with pytest.raises(TypeError, match="does not import it"):
        local()
    assert list(cache.iterdir()) == []


def test_benchmark_times_a_cold_and_a_warm_build(capsys):
    geometry_benchmark.main(["--scenarios", "geo-snr-stations", "--runs", "1"])
    table = capsys.readouterr().out.splitlines()
    assert table[0].startswith("| scenario | first build s")
    assert table[2].startswith("| geo-snr-stations | ")
    assert float(table[2].split("|")[-2]) > 0.0  # the entry was written
