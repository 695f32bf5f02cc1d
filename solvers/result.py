"""The one result type every attitude solver returns.

A solver always works on a batch of epochs (a single epoch is a batch of
one).  Invalid epochs keep NaN attitude, covariance and loss, ``valid`` False
and the reason; :meth:`BatchSolution.epoch` turns one epoch into an
:class:`AttitudeSolution` or raises the specific exception recorded for it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation


@dataclass(frozen=True)
class AttitudeSolution:
    """One epoch's estimate.

    Attributes:
        method: registry name of the solver.
        attitude: ``A`` with ``b = A r`` (``attopt.formulations.conventions``).
        covariance: ``(3, 3)`` attitude-error covariance, rad^2, body frame.
        loss: the problem's loss at ``attitude`` (Wahba's loss, seed 002 eq. 14).
        diagnostics: iterations, certificates and other per-method numbers.
    """

    method: str
    attitude: Rotation
    covariance: NDArray[np.float64]
    loss: float
    diagnostics: Mapping[str, float]


@dataclass(frozen=True)
class BatchSolution:
    """Estimates for ``N`` epochs with a per-epoch validity mask.

    Attributes:
        method: registry name of the solver.
        quaternion: ``(N, 4)`` scipy scalar-last quaternions of ``A``; NaN where invalid.
        covariance: ``(N, 3, 3)`` rad^2, body frame; NaN where invalid.
        loss: ``(N,)``; NaN where invalid.
        valid: ``(N,)`` bool.
        reason: ``(N,)`` str, empty where valid.
        error: ``(N,)`` exception class for invalid epochs, None where valid.
        diagnostics: name -> ``(N,)`` array.
    """

    method: str
    quaternion: NDArray[np.float64]
    covariance: NDArray[np.float64]
    loss: NDArray[np.float64]
    valid: NDArray[np.bool_]
    reason: NDArray[np.object_]
    error: NDArray[np.object_]
    diagnostics: Mapping[str, NDArray[np.float64]]

    def __len__(self) -> int:
        return self.valid.shape[0]

    def attitude(self) -> Rotation:
        """Attitudes of the valid epochs (use ``valid`` to place them)."""
        return Rotation.from_quat(self.quaternion[self.valid])

    def epoch(self, i: int) -> AttitudeSolution:
        """Epoch ``i`` as a single solution; raises its recorded exception if invalid."""
        if not self.valid[i]:
            raise self.error[i](f"{self.method}: {self.reason[i]}")
        return AttitudeSolution(
            method=self.method,
            attitude=Rotation.from_quat(self.quaternion[i]),
            covariance=self.covariance[i],
            loss=float(self.loss[i]),
            diagnostics={k: float(v[i]) for k, v in self.diagnostics.items()},
        )
