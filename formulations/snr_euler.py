"""The SNR model of Liu et al. 2023 parametrised by 3-2-1 Euler angles (eqs. 8, 13, 18).

The NLSE of Liu et al. 2023 sec. 3.3 estimates ``z = [psi, theta, phi]`` (yaw, pitch,
roll).  :func:`euler321_matrix` is eq. 8 written symbolically (CasADi), the
same attitude as :func:`attopt.formulations.conventions.attitude_from_euler321`
(pinned in ``tests/test_snr_solvers.py``), and
:func:`snr_euler_jacobian_function` composes it with the one model definition
:func:`attopt.formulations.snr_model.snr_db`, so the Jacobian ``d f / d z`` of eq. 21
is CasADi's automatic derivative.
"""

from __future__ import annotations

from functools import lru_cache

import casadi as ca

from attopt.formulations.errors import InvalidObservationError
from attopt.formulations.snr_model import (
    Pattern,
    input_names,
    pattern_snr_model,
    symbolic_inputs,
)


def euler321_matrix(angles: ca.SX | ca.MX) -> ca.SX | ca.MX:
    """``C_o^B = R1(phi) R2(theta) R3(psi)`` (Liu et al. 2023 eq. 8) of
    ``angles = [psi, theta, phi]``."""
    psi, theta, phi = angles[0], angles[1], angles[2]
    cps, sps = ca.cos(psi), ca.sin(psi)
    cth, sth = ca.cos(theta), ca.sin(theta)
    cph, sph = ca.cos(phi), ca.sin(phi)
    rows = [
        [cth * cps, cth * sps, -sth],
        [sph * sth * cps - cph * sps, sph * sth * sps + cph * cps, sph * cth],
        [cph * sth * cps + sph * sps, cph * sth * sps - sph * cps, cph * cth],
    ]
    return ca.vertcat(*(ca.horzcat(*row) for row in rows))


@lru_cache(maxsize=16)
def euler321_matrix_function() -> ca.Function:
    """``[psi, theta, phi] -> C_o^B`` (3 x 3), Liu et al. 2023 eq. 8."""
    z = ca.SX.sym("z", 3)
    return ca.Function("euler321_matrix", [z], [euler321_matrix(z)], ["z"], ["attitude"])


@lru_cache(maxsize=64)
def snr_euler_jacobian_function(pattern: Pattern, m: int) -> ca.Function:
    """``(z[3], los[m x 3], boresight[m x 3], p0[m], noise[, antenna[m]]) ->
    (snr[m], d snr / d z [m x 3])``.

    ``snr`` is eq. 13 at the attitude ``euler321_matrix(z)`` (eq. 18 without
    noise); the inputs after ``z`` are
    :func:`attopt.formulations.snr_model.symbolic_inputs` (``antenna`` with one
    pattern per antenna); they are not checked (use
    :func:`attopt.formulations.snr_problem.epoch_issue`).
    """
    if m < 1:
        raise InvalidObservationError(f"need at least one observation, got m = {m}")
    z = ca.SX.sym("z", 3)
    data = symbolic_inputs(pattern, m)
    snr = pattern_snr_model(pattern)(euler321_matrix(z), *data)
    return ca.Function(
        "snr_euler_jacobian",
        [z, *data],
        [snr, ca.jacobian(snr, z)],
        ["z", *input_names(pattern)],
        ["snr_db", "jac_z"],
    )
