"""IPOPT settings and statuses shared by the NLP solvers (the SNR NLP and the MAP NLP).

Both NLPs are built with CasADi's ``nlpsol`` and minimise a loss in units of
the measurement variance (every residual is weighted by its inverse noise
covariance), so one set of stopping tolerances suits both; why each value
is what it is is explained in :mod:`attopt.solvers.snr.nlp`.  Only
:data:`CONVERGED_STATUS` converges; :data:`ACCEPTABLE_STATUS` (IPOPT's relaxed
tolerance held for ``acceptable_iter`` iterations) is accepted and flagged.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Literal

CONVERGED_STATUS = "Solve_Succeeded"
ACCEPTABLE_STATUS = "Solved_To_Acceptable_Level"
ACCEPTED_STATUSES = (CONVERGED_STATUS, ACCEPTABLE_STATUS)


@dataclass(frozen=True)
class IpoptOptions:
    """IPOPT settings of an NLP (:mod:`attopt.solvers.snr.nlp`); hashable, part of cache keys."""

    tol: float = 1e-6
    acceptable_tol: float = 1e-4
    acceptable_iter: int = 15
    max_iter: int = 100
    hessian_approximation: Literal["exact", "limited-memory"] = "exact"
    nlp_scaling_method: Literal["none", "gradient-based"] = "none"

    def nlpsol_options(self) -> dict[str, Any]:
        """``nlpsol`` options: these settings, silent, no multipliers (unconstrained NLPs)."""
        ipopt = {f"ipopt.{k}": v for k, v in asdict(self).items()}
        return {
            **ipopt,
            "ipopt.print_level": 0,
            "ipopt.sb": "yes",
            "print_time": False,
            "show_eval_warnings": False,
            "calc_lam_p": False,
            "calc_lam_x": False,
        }
