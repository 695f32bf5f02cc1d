"""The two result types every estimator returns: a :class:`Solution` and a :class:`Track`.

A *snapshot* estimator turns one epoch's measurements into a
:class:`Solution`; a *pass* estimator (a filter, smoother or batch least
squares) turns a pass into a :class:`Track`, one estimate per epoch.  A
snapshot estimator run over many epochs also returns a :class:`Track`.

Conventions (``docs/conventions.md``): the attitude ``A`` maps reference to
body components, ``b = A r``; quaternions are scipy's, scalar last
``[x, y, z, w]``; covariances are of the body-frame attitude error (rad^2) and
the error of an estimate is the rotation vector of ``estimate * truth.inv()``.
An epoch that is not valid carries NaN attitude, covariance and loss, the
reason and the exception a single-epoch call raises.  An axis the data cannot
see has an infinite variance: its sigma and its error are reported as NaN,
never as a number (:meth:`Track.to_dataframe`).

Example::

    >>> import numpy as np
    >>> from attopt import Snapshot, estimator
    >>> snapshot = Snapshot.from_vectors(
    ...     body=[[1, 0, 0], [0, 1, 0]], reference=[[1, 0, 0], [0, 1, 0]], sigma=1e-3
    ... )
    >>> solution = estimator("quest").solve(snapshot)
    >>> solution.valid, np.round(solution.sigma_deg, 3).tolist()
    (True, [0.057, 0.057, 0.041])
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from attopt.formulations.errors import AttoptError, ConvergenceError

if TYPE_CHECKING:
    from matplotlib.figure import Figure

Array = NDArray[np.float64]

AXES = ("x", "y", "z")
"""Body axes: x roll, y pitch, z yaw (``docs/conventions.md``)."""
TO_DEG_H = np.degrees(1.0) * 3600.0
"""rad/s -> deg/h (gyro bias columns)."""


def observable_sigma(covariance: Array) -> Array:
    """Per-axis standard deviations ``(..., 3)`` of ``(..., 3, 3)`` covariances, NaN where the
    variance is not finite (an axis the data cannot see) or the covariance is NaN."""
    variance = np.diagonal(np.asarray(covariance, dtype=float), axis1=-2, axis2=-1)
    with np.errstate(invalid="ignore"):
        return np.where(np.isfinite(variance) & (variance >= 0), np.sqrt(np.abs(variance)), np.nan)


def attitude_errors(quaternion: Array, truth: Rotation) -> Array:
    """Body-frame error rotation vectors ``(N, 3)`` (rad) of ``estimate * truth.inv()``;
    NaN rows where the estimate is NaN (an invalid epoch)."""
    quaternion = np.asarray(quaternion, dtype=float).reshape(-1, 4)
    error = np.full((quaternion.shape[0], 3), np.nan)
    known = np.isfinite(quaternion).all(axis=1)
    if known.any():
        truth = Rotation.concatenate([truth])  # one or N rotations, quaternions as stored
        error[known] = (Rotation.from_quat(quaternion[known]) * truth[known].inv()).as_rotvec()
    return error


def normalised_errors(error: Array, covariance: Array) -> Array:
    """NEES ``e^T P^-1 e`` per epoch over the axes the covariance bounds; NaN where no axis
    is bounded or the epoch is invalid (``docs/conventions.md``)."""
    error = np.asarray(error, dtype=float).reshape(-1, 3)
    covariance = np.asarray(covariance, dtype=float).reshape(-1, 3, 3)
    nees = np.full(error.shape[0], np.nan)
    bounded = np.isfinite(np.diagonal(covariance, axis1=1, axis2=2))
    for pattern in np.unique(bounded, axis=0):
        if not pattern.any():
            continue
        rows = np.flatnonzero((bounded == pattern).all(axis=1) & np.isfinite(error).all(axis=1))
        axes = np.flatnonzero(pattern)
        block = covariance[np.ix_(rows, axes, axes)]
        good = np.isfinite(block).all(axis=(1, 2))
        e = error[np.ix_(rows[good], axes)]
        nees[rows[good]] = np.einsum("ei,eij,ej->e", e, np.linalg.inv(block[good]), e)
    return nees


class _Uncertainty:
    """Per-axis standard deviations of a result's ``covariance``."""

    covariance: Array

    @property
    def sigma(self) -> Array:
        """Standard deviations per body axis (rad), ``(3,)`` for a solution and ``(N, 3)``
        for a track; NaN where not valid or where the axis is unobservable."""
        return observable_sigma(self.covariance)

    @property
    def sigma_deg(self) -> Array:
        """:attr:`sigma` in degrees."""
        return np.degrees(self.sigma)


@dataclass(frozen=True, eq=False)
class Solution(_Uncertainty):
    """One epoch's estimate.

    Attributes:
        method: registry name of the estimator.
        quaternion: ``(4,)`` scalar-last quaternion of ``A`` (``b = A r``; scipy's
            canonical sign), NaN when not valid; :attr:`attitude` is its ``Rotation``.
        covariance: ``(3, 3)`` attitude-error covariance, rad^2, body frame
            (infinite variances on axes the data cannot see; NaN when not valid).
        loss: the problem's loss at the estimate (e.g. Wahba's loss), NaN if none.
        diagnostics: iterations, certificates and other per-method numbers.
        valid: whether the estimate may be used.
        reason: why not, empty when valid.
        error: the exception class :meth:`raise_if_invalid` raises, ``None`` when valid.
        t: epoch time (s), NaN when not given.

    Example::

        >>> import numpy as np
        >>> from attopt import Snapshot, estimator
        >>> from attopt import attitude_from_euler321
        >>> truth = attitude_from_euler321(*np.radians([30.0, -10.0, 5.0]))
        >>> vectors = np.eye(3)[:2]
        >>> snapshot = Snapshot.from_vectors(truth.apply(vectors), vectors, 1e-3)
        >>> solution = estimator("quest").solve(snapshot)
        >>> solution  # doctest: +NORMALIZE_WHITESPACE
        Solution('quest', yaw/pitch/roll 30.000 / -10.000 / 5.000 deg,
                 sigma x/y/z 0.0569 / 0.0572 / 0.0413 deg)
        >>> list(solution.to_dataframe(truth).columns)[-5:]
        ['reason', 'err_x_deg', 'err_y_deg', 'err_z_deg', 'nees']
    """

    method: str
    quaternion: Array
    covariance: Array
    loss: float = np.nan
    diagnostics: Mapping[str, float] = field(default_factory=dict)
    valid: bool = True
    reason: str = ""
    error: type[AttoptError] | None = None
    t: float = np.nan

    @cached_property
    def attitude(self) -> Rotation | None:
        """The attitude ``A`` of :attr:`quaternion`, ``None`` when not valid (built when first
        asked for: a scipy ``Rotation`` costs more than a fast solver's whole call)."""
        return Rotation.from_quat(self.quaternion) if self.valid else None

    def raise_if_invalid(self) -> Solution:
        """Return ``self`` if valid, else raise the recorded exception with the reason."""
        if not self.valid:
            error = self.error or AttoptError
            raise error(f"{self.method}: {self.reason}")
        return self

    def to_dataframe(self, truth: Rotation | None = None) -> pd.DataFrame:
        """One row: the columns of :meth:`Track.to_dataframe` (``truth``: one rotation)."""
        if truth is not None and truth.single:
            truth = Rotation.concatenate([truth])
        return Track.from_solutions([self]).to_dataframe(truth)

    def __repr__(self) -> str:
        if not self.valid:
            return f"Solution({self.method!r}, invalid: {self.reason})"
        sigma = " / ".join(f"{s:.3g}" for s in self.sigma_deg)
        euler = np.degrees(self.attitude.inv().as_euler("ZYX"))
        angles = " / ".join(f"{a:.3f}" for a in euler)
        return f"Solution({self.method!r}, yaw/pitch/roll {angles} deg, sigma x/y/z {sigma} deg)"


@dataclass(frozen=True, eq=False)
class Track(_Uncertainty):
    """Estimates at ``N`` epochs with a per-epoch validity mask.

    Attributes:
        method: registry name of the estimator.
        quaternion: ``(N, 4)`` scalar-last quaternions of ``A``; NaN where invalid.
        covariance: ``(N, 3, 3)`` attitude-error covariance, rad^2, body frame;
            NaN where invalid, infinite variances on axes the data cannot see.
        loss: ``(N,)`` the problem's loss or the update's normalised innovation
            squared; NaN where invalid or absent.
        valid: ``(N,)`` bool.
        reason: ``(N,)`` str, empty where valid.
        error: ``(N,)`` exception class of invalid epochs, ``None`` where valid.
        diagnostics: name -> ``(N,)`` array.
        t: ``(N,)`` epoch times (s), or ``None`` when not known.
        bias: ``(N, 3)`` gyro bias estimates (rad/s) of gyro-aided estimators.
        rate: ``(N, 3)`` body-rate estimates (rad/s) of dynamics-based estimators.
        state_covariance: ``(N, n, n)`` covariance of the whole error state,
            whose three-component blocks are named by ``state``.
        state: names of the error state's blocks, e.g. ``("attitude", "bias")``.
        history: what a backward (RTS) pass needs, for filters that keep it.
        report: the optimiser's or pass's own report (smoothers), if any.

    Example::

        >>> import numpy as np
        >>> from scipy.spatial.transform import Rotation
        >>> from attopt import Snapshot, estimator
        >>> vectors = np.eye(3)[:2]
        >>> track = estimator("quest").solve_sequence(
        ...     [Snapshot.from_vectors(vectors, vectors, 1e-3), None]
        ... )
        >>> track.valid.tolist(), track.reason.tolist()
        ([True, False], ['', 'fewer than two vector observations'])
        >>> track.to_dataframe(Rotation.identity(2))["err_x_deg"].isna().tolist()
        [False, True]
    """

    method: str
    quaternion: Array
    covariance: Array
    loss: Array
    valid: NDArray[np.bool_]
    reason: NDArray[np.object_]
    error: NDArray[np.object_]
    diagnostics: Mapping[str, Array]
    t: Array | None = None
    bias: Array | None = None
    rate: Array | None = None
    state_covariance: Array | None = None
    state: tuple[str, ...] = ("attitude",)
    history: Any = None
    report: Any = None

    def __len__(self) -> int:
        return self.valid.shape[0]

    def attitude(self) -> Rotation:
        """Attitudes of the valid epochs (use ``valid`` to place them)."""
        return Rotation.from_quat(self.quaternion[self.valid])

    def block(self, name: str) -> slice:
        """The rows of block ``name`` (``"attitude"``, ``"bias"``, ``"rate"``) in the state."""
        i = self.state.index(name)
        return slice(3 * i, 3 * i + 3)

    def epoch(self, i: int) -> Solution:
        """Epoch ``i`` as a :class:`Solution` (valid or not)."""
        valid = bool(self.valid[i])
        return Solution(
            method=self.method,
            quaternion=(
                Rotation.from_quat(self.quaternion[i]).as_quat(canonical=True)
                if valid
                else np.full(4, np.nan)
            ),
            covariance=self.covariance[i],
            loss=float(self.loss[i]),
            diagnostics={k: float(v[i]) for k, v in self.diagnostics.items()},
            valid=valid,
            reason=str(self.reason[i]),
            error=self.error[i],
            t=np.nan if self.t is None else float(self.t[i]),
        )

    def flagged(
        self, mask: NDArray[np.bool_], reason: str, error: type[AttoptError] = ConvergenceError
    ) -> Track:
        """This track with the valid epochs of ``mask`` flagged with ``reason`` and
        ``error``: their estimates, covariances, loss, bias or rate NaN (epochs already
        invalid keep their reason).

        Example::

            >>> import numpy as np
            >>> from attopt import Snapshot, estimator
            >>> vectors = np.eye(3)[:2]
            >>> track = estimator("quest").solve_sequence(
            ...     [Snapshot.from_vectors(vectors, vectors, 1e-3)] * 2
            ... )
            >>> track.flagged(np.array([False, True]), "converging").reason.tolist()
            ['', 'converging']
        """
        hit = np.asarray(mask, dtype=bool) & self.valid

        def blank(values: Array | None) -> Array | None:
            if values is None:
                return None
            values = np.asarray(values, dtype=float)
            return np.where(hit.reshape(-1, *([1] * (values.ndim - 1))), np.nan, values)

        return replace(
            self,
            quaternion=blank(self.quaternion),
            covariance=blank(self.covariance),
            loss=blank(self.loss),
            valid=self.valid & ~hit,
            reason=np.where(hit, reason, self.reason).astype(object),
            error=np.where(hit, error, self.error),
            bias=blank(self.bias),
            rate=blank(self.rate),
            state_covariance=blank(self.state_covariance),
        )

    @classmethod
    def from_solutions(cls, solutions: list[Solution]) -> Track:
        """The track of single-epoch solutions (one estimator's, in epoch order)."""
        if not solutions:
            raise ValueError("need at least one solution")
        names = sorted({name for s in solutions for name in s.diagnostics})
        error = np.full(len(solutions), None, dtype=object)
        error[:] = [s.error for s in solutions]
        return cls(
            method=solutions[0].method,
            quaternion=np.array([s.quaternion for s in solutions]),
            covariance=np.array([s.covariance for s in solutions], dtype=float),
            loss=np.array([s.loss for s in solutions], dtype=float),
            valid=np.array([s.valid for s in solutions], dtype=bool),
            reason=np.array([s.reason for s in solutions], dtype=object),
            error=error,
            diagnostics={
                n: np.array([s.diagnostics.get(n, np.nan) for s in solutions]) for n in names
            },
            t=np.array([s.t for s in solutions], dtype=float),
        )

    def to_dataframe(self, truth: Rotation | None = None) -> pd.DataFrame:
        """One row per epoch.

        Columns: ``t`` (s; NaN when not known), the estimate's quaternion
        ``qx, qy, qz, qw`` (scalar last), ``sigma_{x,y,z}_deg`` per body axis,
        ``valid`` and ``reason``; gyro-aided tracks add ``bias_{x,y,z}_deg_h``.
        Given ``truth`` (``N`` rotations), ``err_{x,y,z}_deg`` (the rotation
        vector of ``estimate * truth.inv()``) and ``nees`` (over the bounded
        axes).  Invalid epochs, and axes the data cannot see, are NaN.
        """
        n = len(self)
        sigma = self.sigma_deg
        columns: dict[str, Any] = {"t": np.full(n, np.nan) if self.t is None else self.t}
        columns |= {f"q{c}": self.quaternion[:, i] for i, c in enumerate("xyzw")}
        columns |= {f"sigma_{a}_deg": sigma[:, i] for i, a in enumerate(AXES)}
        columns["valid"] = self.valid
        columns["reason"] = self.reason.astype(str)
        if self.bias is not None:
            columns |= {f"bias_{a}_deg_h": TO_DEG_H * self.bias[:, i] for i, a in enumerate(AXES)}
        if truth is not None:
            if len(truth) != n:
                raise ValueError(f"truth has {len(truth)} attitudes for {n} epochs")
            error = attitude_errors(self.quaternion, truth)
            nees = normalised_errors(error, self.covariance)
            error[~np.isfinite(sigma)] = np.nan
            columns |= {f"err_{a}_deg": np.degrees(error[:, i]) for i, a in enumerate(AXES)}
            columns["nees"] = nees
        return pd.DataFrame(columns)

    def plot(self, truth: Rotation | None = None, ax: Any = None) -> Figure:
        """Error (given ``truth``) or estimate per body axis with its +/-3 sigma band.

        Without ``truth`` the estimate is drawn as 3-2-1 Euler angles (roll,
        pitch, yaw about x, y, z) with the band around it.  Returns the figure
        (``ax``: three axes to draw into).
        """
        from attopt.solvers.plotting import plot_track

        return plot_track(self, truth, ax)

    def __repr__(self) -> str:
        n, valid = len(self), int(self.valid.sum())
        span = ""
        if self.t is not None and n and np.isfinite(self.t).any():
            span = f", t {np.nanmin(self.t):g}-{np.nanmax(self.t):g} s"
        sigma = ""
        if valid:
            with np.errstate(invalid="ignore"):
                median = np.nanmedian(np.where(self.valid[:, None], self.sigma_deg, np.nan), axis=0)
            sigma = ", median sigma x/y/z " + " / ".join(f"{s:.3g}" for s in median) + " deg"
        return f"Track({self.method!r}, {n} epochs, {valid} valid{span}{sigma})"
