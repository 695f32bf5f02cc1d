"""Compiled gradient and Hessian of the SNR NLP, for IPOPT.

IPOPT evaluates the NLP's gradient and the Hessian of its Lagrangian at every
iteration (both objectives, :data:`~attopt.solvers.snr.fit.OBJECTIVES`). Built in
CasADi's SX from the loss over ``size`` rows, as
:func:`~attopt.solvers.snr.nlp.nlp_solver` builds it, they run in CasADi's
interpreter; for the truncated likelihood (``log Phi`` of every row,
:func:`~attopt.solvers.snr.fit.truncated_loss`) the Hessian is most of a solve:
5.3-5.6 of 9.0 ms at 256 rows (its three evaluations). Compiling those SX functions
as they are takes minutes (43 s for the gradient and 381 s for the Hessian at 256
rows: the C is unrolled over the rows). Here instead the loss of ONE row, its
gradient and its Hessian are SX functions (CasADi's AD of the row), mapped over the
rows with the shared inputs (``v``, ``A_ref``, the noise power, the threshold) and
summed (CasADi ``map`` with ``reduce_in`` and ``reduce_out``); the sums are
generated as C with a loop over the rows and compiled by
:func:`attopt.formulations.kernels.kernel` (0.3 s and 0.75 s at 256 rows, once per
machine and size, cached on disk). IPOPT takes them through ``nlpsol``'s ``grad_f``
and ``hess_lag`` options; the objective itself stays the SX loss. Measured for the
truncated likelihood on whole ``adsb-snr`` epochs (about 170 SNRs, 256 rows padded):
10.7-11.3 ms a solve against 3.1-4.1 ms, the estimates within 4e-16 rad (``python -m
attopt.experiments.benchmarks.snr``, ``docs/benchmarks.md``).

The least squares gain less, IPOPT's own cost being most of their solve: 2.6 ms
against 2.0 ms at 256 rows, 1.42 ms against 1.24 ms at 32 rows (the truncated
likelihood 2.53 ms against 1.47 ms). A first version took CasADi's MX derivatives
through the map of the rows' losses: at 256 rows the least squares were no faster
(3.0 ms against 2.8 ms), every row recomputing ``C(v) A_ref`` and its derivatives, and
the Hessian of a cosine-power pattern's floor was NaN where the SX one is finite.
Not for the SQP method (its derivative options differ) or the limited-memory
Hessian; and not when the kernels are interpreted (``ATTOPT_KERNELS=interpreted``)
or cannot be compiled: the mapped functions interpreted are slower than the SX ones
(the truncated Hessian at 256 rows 4.9 ms against 2.1 ms), so the NLP then keeps
CasADi's own derivatives.

The map sums the rows in another order than the SX graph: the derivatives agree
to round-off (``tests/test_nlp_derivatives.py``), the estimates to the stopping
tolerance.
"""

from __future__ import annotations

from functools import lru_cache

import casadi as ca

from attopt.formulations.gain_patterns import AntennaPatterns
from attopt.formulations.kernels import compiled_kernels, kernel
from attopt.formulations.snr_model import Pattern, snr_function
from attopt.solvers.nlpsol import NlpOptions
from attopt.solvers.snr.fit import Objective, objective_loss

SHARED = ("attitude_ref", "noise", "threshold")
"""Parameters every row shares (the rest are one value, or one row of 3, per row)."""
ROW_VECTORS = ("los", "boresight")
"""Parameters of 3 values per row (``size x 3``)."""


def compiled_derivatives(
    pattern: Pattern,
    size: int,
    objective: Objective,
    options: NlpOptions,
    symbols: dict[str, ca.SX],
) -> dict[str, ca.Function]:
    """``nlpsol`` options ``grad_f`` and ``hess_lag`` of the NLP whose parameters are
    ``symbols`` (:func:`~attopt.solvers.snr.nlp._parameter_symbols`, in their order),
    compiled (module docstring), or ``{}`` where they do not apply."""
    if not (
        options.solver == "ipopt"
        and options.hessian_approximation == "exact"
        and compiled_kernels()
    ):
        return {}
    gradient, hessian = _derivatives(pattern, size, objective, tuple(symbols))
    compiled = kernel(gradient), kernel(hessian)
    if compiled[0] is gradient or compiled[1] is hessian:  # not compiled: a warning was logged
        return {}
    return {"grad_f": compiled[0], "hess_lag": compiled[1]}


@lru_cache(maxsize=32)
def _derivatives(
    pattern: Pattern, size: int, objective: Objective, names: tuple[str, ...]
) -> tuple[ca.Function, ca.Function]:
    """The gradient ``(x, p) -> (f, grad_f_x)`` and upper-triangular Hessian
    ``(x, p, lam_f, lam_g) -> hess_gamma_x_x`` of the rows' loss: each row's loss, gradient
    and Hessian by CasADi's AD of one row in SX, mapped over the rows and summed (module
    docstring)."""
    from attopt.solvers.snr.nlp import _parameter_symbols  # nlp imports this module

    per_antenna = isinstance(pattern, AntennaPatterns)
    row = _parameter_symbols(1, objective, per_antenna)
    v = ca.SX.sym("v", 3)
    data = [row[name] for name in ("los", "boresight", "p0", "noise", "antenna") if name in row]
    loss = objective_loss(
        objective,
        row["snr"],
        snr_function(pattern, 1)(v, row["attitude_ref"], *data),
        row["weights"],
        row.get("sigma"),
        row.get("threshold"),
    )
    inputs = [v, *row.values()]
    shared = [0] + [1 + i for i, name in enumerate(names) if name in SHARED]
    row_gradient = ca.Function("snr_row_gradient", inputs, [loss, ca.gradient(loss, v)])
    row_hessian = ca.Function("snr_row_hessian", inputs, [ca.triu(ca.hessian(loss, v)[0])])

    full = _parameter_symbols(size, objective, per_antenna)
    x = ca.MX.sym("x", 3)
    p = {name: ca.MX.sym(name, *full[name].shape) for name in names}
    arguments = [x] + [_mapped_argument(name, p[name], size) for name in names]
    parameters = ca.vertcat(*(ca.vec(p[name]) for name in names))
    suffix = f"{objective}_{size}"
    total, gradient = row_gradient.map("snr_rows_gradient", "serial", size, shared, [0, 1])(
        *arguments
    )
    hessian = row_hessian.map("snr_rows_hessian", "serial", size, shared, [0])(*arguments)
    lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", 0)
    return (
        ca.Function(
            f"snr_nlp_grad_f_{suffix}",
            [x, parameters],
            [total, gradient],
            ["x", "p"],
            ["f", "grad_f_x"],
        ),
        ca.Function(
            f"snr_nlp_hess_l_{suffix}",
            [x, parameters, lam_f, lam_g],
            [lam_f * hessian],
            ["x", "p", "lam_f", "lam_g"],
            ["hess_gamma_x_x"],
        ),
    )


def _mapped_argument(name: str, symbol: ca.MX, size: int) -> ca.MX:
    """``symbol`` as the map takes it: shared as it is, a ``size x 3`` matrix as its rows
    side by side (``1 x 3 size``), a column of ``size`` values as a row."""
    if name in SHARED:
        return symbol
    if name in ROW_VECTORS:
        return ca.reshape(symbol.T, 1, 3 * size)
    return symbol.T
