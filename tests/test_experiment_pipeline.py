"""The experiments' shared pieces: names checked against the registry, the simulated world
apart from the estimators, and the metric columns of a track."""

from __future__ import annotations

import ast
import importlib.util
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from scipy.spatial.transform import Rotation

from attopt.experiments.adsb_snr.experiment import EXPERIMENT as ADSB
from attopt.experiments.doa_ground.experiment import EXPERIMENT as DOA
from attopt.experiments.estimators import resolve
from attopt.experiments.metrics import error_columns, pointing_error
from attopt.experiments.sweep import run_sweep
from attopt.experiments.wahba_mag_sun.experiment import EXPERIMENT as WAHBA
from attopt.formulations.attitude_measurement import VectorMeasurement
from attopt.formulations.snr_measurement import SnrMeasurement
from attopt.solvers.registry import estimators
from attopt.solvers.results import Track
from tests.strategies import attitudes

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize(
    ("experiment", "override", "names"),
    [
        (WAHBA, {"methods": ["quest", "davenport"]}, estimators("snapshot", VectorMeasurement)),
        (WAHBA, {"filters": ["mekf", "ukf"]}, estimators("pass", VectorMeasurement)),
        (ADSB, {"methods": ["nlp", "mekf"]}, estimators("snapshot", SnrMeasurement)),
        (ADSB, {"filters": ["mekf_snr", "ekf"]}, estimators("pass", SnrMeasurement)),
        (DOA, {"filters": ["mekf", "ukf"]}, estimators("pass", VectorMeasurement)),
    ],
)
def test_an_unknown_name_fails_listing_the_registered_ones(experiment, override, names):
    unknown = override[next(iter(override))][-1]
    with pytest.raises(ValueError, match=rf"unknown \w+ \['{unknown}'\]; registered: ") as error:
        experiment.grid({**experiment.parameters, **override})
    listed = str(error.value).split("registered: ")[1]
    assert set(names) <= set(re.findall(r"\w+", listed))


def test_an_unknown_method_fails_the_sweep_before_any_trial(tmp_path):
    with pytest.raises(ValueError, match=r"unknown methods \['davenport'\]; registered: triad"):
        run_sweep(
            WAHBA,
            trials=1,
            out=tmp_path,
            workers=1,
            progress=False,
            overrides={"methods": ["svd", "davenport"]},
        )
    assert not (tmp_path / "rows").exists()


def test_resolve_maps_labels_in_the_order_asked():
    labels = {"mekf_snr": "mekf", "fg_batch": "fg_batch"}
    assert list(resolve(["fg_batch", "mekf_snr"], labels, "filters").items()) == [
        ("fg_batch", "fg_batch"),
        ("mekf_snr", "mekf"),
    ]
    with pytest.raises(ValueError, match=r"registered: mekf_snr \(mekf\), fg_batch$"):
        resolve(["rts"], labels, "filters")


def _module_file(name: str) -> Path | None:
    spec = importlib.util.find_spec(name)
    return Path(spec.origin) if spec is not None and spec.origin else None


def _attopt_imports(path: Path) -> set[str]:
    """The attopt modules ``path`` imports (absolute imports, as the project writes them)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
        elif isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
    return {name for name in found if name.startswith("attopt.")}


def _solver_imports(start: Path) -> list[tuple[str, str]]:
    """``(module, solver module)`` for every import of ``attopt.solvers`` reachable from
    ``start`` through the project's other modules (package facades excluded)."""
    seen: set[Path] = set()
    bad = []
    todo = [start]
    while todo:
        path = todo.pop()
        if path in seen:
            continue
        seen.add(path)
        for name in _attopt_imports(path):
            if name.startswith("attopt.solvers"):
                bad.append((str(path.relative_to(ROOT)), name))
                continue
            target = _module_file(name)
            if target is not None and target.name != "__init__.py":
                todo.append(target)
    return bad


WORLD = sorted(
    [*ROOT.glob("experiments/*/scenario.py"), *ROOT.glob("experiments/environment/*.py")]
)


def test_the_world_modules_are_found():
    names = {str(p.relative_to(ROOT)) for p in WORLD}
    assert {
        "experiments/doa_ground/scenario.py",
        "experiments/geo_snr_stations/scenario.py",
    } <= names
    assert "experiments/environment/orbit.py" in names and len(names) >= 10


@pytest.mark.parametrize("path", WORLD, ids=lambda p: str(p.relative_to(ROOT)))
def test_the_simulated_world_imports_no_estimator(path):
    """Scenarios and the environment model the world: they import nothing from
    ``attopt.solvers``, directly or through the modules they import."""
    assert _solver_imports(path) == []


def test_the_import_check_sees_a_solver_import_through_another_module():
    assert _solver_imports(ROOT / "experiments" / "simulation.py") == []
    found = _solver_imports(ROOT / "experiments" / "metrics.py")
    assert ("experiments/metrics.py", "attopt.solvers.bounds") in found


def _track(quaternion: np.ndarray, covariance: np.ndarray, valid: np.ndarray) -> Track:
    n = len(valid)
    return Track(
        method="test",
        quaternion=np.where(valid[:, None], quaternion, np.nan),
        covariance=np.where(valid[:, None, None], covariance, np.nan),
        loss=np.full(n, np.nan),
        valid=valid,
        reason=np.where(valid, "", "flagged").astype(object),
        error=np.full(n, None, dtype=object),
        diagnostics={},
    )


@settings(max_examples=25, deadline=None)
@given(truth=attitudes())
def test_error_columns_are_track_to_dataframes_columns(truth):
    """One implementation: the experiments' error, sigma and NEES columns are those of
    ``Track.to_dataframe`` (bitwise), also with an axis the covariance cannot see."""
    rng = np.random.default_rng(7)
    n = 6
    truths = Rotation.concatenate(
        [Rotation.from_rotvec(0.1 * rng.standard_normal(3)) * truth for _ in range(n)]
    )
    estimate = Rotation.from_rotvec(1e-3 * rng.standard_normal((n, 3))) * truths
    factor = rng.standard_normal((n, 3, 3))
    covariance = 1e-6 * (factor @ factor.transpose(0, 2, 1) + np.eye(3))
    covariance[4:, 2, :] = covariance[4:, :, 2] = 0.0
    covariance[4:, 2, 2] = np.inf
    valid = np.array([True, True, False, True, True, True])
    track = _track(estimate.as_quat(), covariance, valid)
    ours = error_columns(track, truths)
    frame = track.to_dataframe(truths)
    for column in ("err_x_deg", "err_y_deg", "err_z_deg", "sigma_x_deg", "sigma_z_deg", "nees"):
        np.testing.assert_array_equal(ours[column], frame[column].to_numpy())
    assert np.isnan(ours["err_z_deg"][[2, 4, 5]]).all() and np.isfinite(ours["err_z_deg"][:2]).all()
    assert np.isnan(ours["sigma_z_deg"][4:]).all() and np.isfinite(ours["nees"][4:]).all()
    error = (estimate[4] * truths[4].inv()).as_rotvec()[:2]
    assert ours["nees"][4] == pytest.approx(error @ np.linalg.solve(covariance[4, :2, :2], error))
    assert np.isnan(ours["euler_yaw_err_deg"][2]) and np.isfinite(ours["euler_yaw_err_deg"][4])


@settings(max_examples=25, deadline=None)
@given(truth=attitudes())
def test_pointing_error_is_the_tilt_of_the_boresight_without_yaw(truth):
    tilt = np.array([2e-3, -1e-3, 0.0])
    yaw = Rotation.from_rotvec([0.0, 0.0, 0.7])  # about the boresight: not seen
    estimate = yaw * Rotation.from_rotvec(tilt) * truth
    boresight = estimate.inv().apply([0.0, 0.0, 1.0])
    error = pointing_error(Rotation.concatenate([truth]), boresight[None])[0]
    np.testing.assert_allclose(error[:2], tilt[:2], atol=1e-9)
    assert np.isnan(error[2])


def test_a_snapshot_estimator_without_a_vectorised_path_runs_on_the_snapshots():
    """``map_nlp`` (solve_sequence over the pass's snapshots) beside QUEST (the Wahba
    solvers' vectorised path) on the same noisy vectors: the same maximum-likelihood
    attitude to well below the noise (0.1 deg)."""
    setting = {**WAHBA.parameters, "duration_s": 40.0, "methods": ["quest", "map_nlp"]}
    rows = WAHBA.trial({**setting, "filters": []}, np.random.SeedSequence(3))
    quest, nlp = (rows[rows["method"] == m].reset_index(drop=True) for m in ("quest", "map_nlp"))
    assert len(quest) == len(nlp) == 40 and quest["valid"].all() and nlp["valid"].all()
    errors = [f"err_{a}_deg" for a in "xyz"]
    np.testing.assert_allclose(nlp[errors], quest[errors], atol=1e-4)
    np.testing.assert_array_equal(nlp["bound_x_deg"], quest["bound_x_deg"])
