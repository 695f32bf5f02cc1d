"""Yang et al. 2014 (DOAs of ground stations): MUSIC, the EKF on rigid-body dynamics,
its RTS smoother and the whole-pass batch least squares.

Registry estimators (:mod:`attopt.solvers.doa.estimators`): ``ekf_yang2014``,
``rts_yang2014`` and ``bls_yang2014``.
"""

from attopt.solvers.doa.estimators import DoaBatchLs, DoaEkf, DoaRts
from attopt.solvers.doa.music import DoaEstimates, MusicEstimator

ESTIMATORS = (DoaEkf(), DoaRts(), DoaBatchLs())
"""The package's registry estimators with their default options."""

__all__ = ["ESTIMATORS", "DoaBatchLs", "DoaEkf", "DoaEstimates", "DoaRts", "MusicEstimator"]
