"""CasADi ``nlpsol`` settings and statuses shared by the NLP solvers (the SNR NLP and the MAP NLP).

Both NLPs are built once with CasADi's ``nlpsol`` and minimise a loss in units of
the measurement variance (every residual is weighted by its inverse noise
covariance), so one set of stopping tolerances suits both; why each value
is what it is is explained in :mod:`attopt.solvers.snr.nlp`.

Solver (:attr:`NlpOptions.solver`): the same NLP, solved by one of two of
CasADi's plugins.

* ``"ipopt"`` (default): IPOPT, the interior-point method of Liu et al. 2023's
  NLP.  Only :data:`CONVERGED_STATUS` converges; :data:`ACCEPTABLE_STATUS`
  (IPOPT's relaxed tolerance held for ``acceptable_iter`` iterations) is accepted
  and flagged.
* ``"sqpmethod"``: CasADi's SQP method with its ``qrqp`` QP solver, the exact
  Hessian made positive definite by ``convexify_strategy = eigen-reflect`` (negative
  eigenvalues reflected: a Newton step where the loss is convex, a descent direction
  of the same scale where it is not; ``regularize`` converged linearly on the SNR
  NLP, a factor 3 per iteration, and ``eigen-clip`` jumped to distant minima),
  stopping when the largest gradient component is below ``tol`` (``tol_du``; and
  ``tol_pr``, though the NLPs have no constraints).  It has no acceptable level:
  ``acceptable_tol``, ``acceptable_iter`` and ``nlp_scaling_method`` apply to IPOPT
  only.  Only :data:`CONVERGED_STATUS` converges.  A solve that stops without
  converging after at least one iteration (its line search does not cut back steps
  into the regions where the SNR loss is undefined, as IPOPT's does) is repeated by
  IPOPT from the same start
  (:func:`attopt.solvers.snr.initialisation.increment_solve`).

Why a second solver. IPOPT costs about 1.4 ms per solve however small the problem: on a
3-variable quadratic it took 0.30-0.45 ms stopped at the start, 0.8-1.2 ms after one
iteration and 1.4-1.65 ms for the four it needs, its algorithm objects built and MUMPS
initialised at every call; the SQP method solved it in 0.12-0.17 ms (``python -m
attopt.experiments.benchmarks.snr``, ``docs/benchmarks.md``). On 20-observation SNR
epochs a warm-started local solve took 0.65 ms against 2.2 ms, and the 24 multi-starts
of 15 epochs 0.32 s against 0.76 s; both converged from 151 of the 360 starts, to the
same minimum from 149. The estimates agree to the stopping tolerance
(``tests/test_nlp_solvers.py``). Where the loss is expensive to evaluate the evaluations
count: over 60 s of ``adsb-snr`` (about 170 SNRs an epoch) ``nlp`` took 0.34 s against
1.28 s, but ``nlp_truncated`` 2.4 s against 1.2 s: IPOPT is given the SNR NLP's compiled
gradient and Hessian (:mod:`attopt.solvers.snr.nlp_derivatives`), the SQP method
evaluates CasADi's own. The multi-start's basins are not quite IPOPT's, so the ambiguity
check (:func:`~attopt.solvers.snr.initialisation.rival_minimum`) may find a second
minimum with one solver and not the other: on that pass IPOPT's found one 52 deg away at
the first epoch, the SQP method's did not (``docs/benchmarks.md``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

CONVERGED_STATUS = "Solve_Succeeded"
ACCEPTABLE_STATUS = "Solved_To_Acceptable_Level"
ACCEPTED_STATUSES = (CONVERGED_STATUS, ACCEPTABLE_STATUS)

NlpSolverName = Literal["ipopt", "sqpmethod"]
SOLVERS: tuple[NlpSolverName, ...] = ("ipopt", "sqpmethod")
"""The ``nlpsol`` plugins an NLP can be solved with (module docstring)."""

_SILENT = {"print_time": False, "show_eval_warnings": False}
_NO_MULTIPLIERS = {"calc_lam_p": False, "calc_lam_x": False}


@dataclass(frozen=True)
class NlpOptions:
    """Settings of an NLP's ``nlpsol`` (module docstring); hashable, part of cache keys.

    Example:
        >>> from attopt.solvers.nlpsol import NlpOptions
        >>> NlpOptions(solver="sqpmethod").nlpsol_options()["tol_du"]
        1e-06
    """

    solver: NlpSolverName = "ipopt"
    tol: float = 1e-6
    acceptable_tol: float = 1e-4
    acceptable_iter: int = 15
    max_iter: int = 100
    hessian_approximation: Literal["exact", "limited-memory"] = "exact"
    nlp_scaling_method: Literal["none", "gradient-based"] = "none"

    def __post_init__(self) -> None:
        for name, accepted in (
            ("solver", SOLVERS),
            ("hessian_approximation", ("exact", "limited-memory")),
            ("nlp_scaling_method", ("none", "gradient-based")),
        ):
            if getattr(self, name) not in accepted:
                raise ValueError(
                    f"unsupported {name} {getattr(self, name)!r}; supported: {accepted}"
                )
        if self.max_iter < 0 or not self.tol > 0:
            raise ValueError(f"max_iter must be >= 0 and tol > 0, got {self.max_iter}, {self.tol}")

    @property
    def label(self) -> str:
        """The solver's name in the reason of a failed epoch: ``IPOPT`` or ``SQP``."""
        return "SQP" if self.solver == "sqpmethod" else "IPOPT"

    def nlpsol_options(self) -> dict[str, Any]:
        """``nlpsol`` options of :attr:`solver`: these settings, silent, no multipliers
        (unconstrained NLPs)."""
        if self.solver == "sqpmethod":
            return {
                "qpsol": "qrqp",
                "qpsol_options": {"print_iter": False, "print_header": False},
                "convexify_strategy": "eigen-reflect",
                "tol_du": self.tol,
                "tol_pr": self.tol,
                "max_iter": self.max_iter,
                "hessian_approximation": self.hessian_approximation,
                "print_header": False,
                "print_iteration": False,
                "print_status": False,
                "error_on_fail": False,
                **_SILENT,
                **_NO_MULTIPLIERS,
            }
        ipopt = {
            "tol": self.tol,
            "acceptable_tol": self.acceptable_tol,
            "acceptable_iter": self.acceptable_iter,
            "max_iter": self.max_iter,
            "hessian_approximation": self.hessian_approximation,
            "nlp_scaling_method": self.nlp_scaling_method,
            "print_level": 0,
            "sb": "yes",
        }
        return {**{f"ipopt.{k}": v for k, v in ipopt.items()}, **_SILENT, **_NO_MULTIPLIERS}
