"""SNR measurement model of ADS-B attitude determination (Liu et al. 2023 sec. 3.1).

``SNR = G(alpha) + 10 lg P0 - 10 lg(k_B T B) + nu`` dB (Liu et al. 2023 eqs. 1-4, 11)
with ``G = 10 lg g`` the receive gain pattern (:mod:`attopt.formulations.gain_patterns`),
``P0`` and the noise power from :mod:`attopt.formulations.link_budget`, and
``cos alpha = (A l_o) . b_B`` (eqs. 5-7, 13): ``A = C_o^B`` the attitude
(orbit to body, ``docs/conventions.md``), ``l_o`` the unit line of sight in the
orbit frame and ``b_B`` the boresight of the receiving antenna in the body frame.

Line of sight: ``l_o`` points from the satellite to the aircraft,
``(x_a - x_s) / |x_a - x_s|``, as the text of eq. 3 defines ``alpha``.  Eq. 9
prints ``x_s - x_a``, which points the other way; with it an antenna looking
down at the aircraft would see them at ``alpha > 90 deg``.  Boresights of
Earth-looking antennas therefore point towards nadir (``+z`` of the orbit
frame at zero attitude).

The model is written once (:func:`snr_db`) with the namespaces of
:mod:`attopt.formulations.symbolic`: numpy arrays give vectorised values over epochs
and observations, CasADi values give expressions from which
:func:`snr_function` and :func:`snr_jacobian_function` build
``casadi.Function`` objects whose Jacobian is CasADi's automatic derivative.
The attitude is varied for optimisation as ``A = C(v) A_ref`` with ``C(v)``
the rotation with modified Rodrigues parameters ``v / 4``
(:func:`increment_matrix`; Liu et al. 2023 eq. 28), so ``v`` is the body-frame
attitude error vector to first order.  :func:`predict_snr` gives numpy values
and the Jacobian with respect to that error, from which
:func:`fisher_information` and :func:`cramer_rao_bound` follow (Liu et al. 2023 eq. 22).

Antennas with different gain patterns: ``pattern`` may be an
:class:`~attopt.formulations.gain_patterns.AntennaPatterns`, one pattern per antenna;
then every function takes ``antenna``, the receiving antenna of each observation
(numpy integers, or one more input of the compiled CasADi functions, after the
noise power), and evaluates each observation with its antenna's pattern.  With one
pattern ``antenna`` is not used and the functions are exactly the single-pattern ones.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_model import (
    attitude_model_function,
    evaluate_at_attitudes,
    increment_matrix,
)
from attopt.formulations.errors import InvalidObservationError
from attopt.formulations.gain_patterns import AntennaPatterns, GainPattern
from attopt.formulations.symbolic import NUMPY, namespace_of

Array = NDArray[np.float64]
Pattern = GainPattern | AntennaPatterns
"""One gain pattern for every antenna, or one per antenna (module docstring)."""

SNR_SIGMA_DB = 1.0
"""SNR measurement noise standard deviation (dB), Liu et al. 2023 sec. 5.1."""

_ROTATION_TOLERANCE = 1e-6
_NULL_PROJECTOR_TOLERANCE = 1e-9


def line_of_sight(
    satellite_position: ArrayLike, aircraft_position: ArrayLike
) -> tuple[Array, Array]:
    """Unit line of sight from the satellite to the aircraft, and the range.

    ``(x_a - x_s) / |x_a - x_s|`` (Liu et al. 2023 eq. 9 with the sign of eq. 3's
    text, see the module docstring), in the frame of the positions (the orbit
    frame for :func:`snr_db`); the range is in the positions' unit.
    """
    delta = np.asarray(aircraft_position, dtype=float) - np.asarray(satellite_position, float)
    distance = np.linalg.norm(delta, axis=-1)
    if not np.all(np.isfinite(distance) & (distance > 0)):
        raise InvalidObservationError("aircraft position is NaN/inf or equals the satellite's")
    return delta / distance[..., None], distance


def off_boresight(attitude_matrix: Any, los_orbit: Any, boresight_body: Any) -> tuple[Any, Any]:
    """``cos(alpha)`` and ``1 - cos(alpha)`` of Liu et al. 2023 eqs. 6-7.

    ``l_B = A l_o / |l_o|`` and ``b = b_B / |b_B|``; ``cos alpha = l_B . b``
    (accurate near 90 deg) and ``1 - cos alpha = |l_B - b|^2 / 2`` (accurate
    near 0 deg).  No ``arccos``: both are polynomial in ``A``, so their
    derivatives are finite everywhere.  numpy: ``A`` is ``(..., 3, 3)``, the
    vectors ``(..., m, 3)``, results ``(..., m)``; CasADi: ``A`` is ``3 x 3``,
    the vectors ``m x 3``, results ``m x 1``.
    """
    xp = namespace_of(attitude_matrix, los_orbit, boresight_body)
    los = xp.components(los_orbit)
    bore = xp.components(boresight_body)
    los_norm = xp.sqrt(los[0] ** 2 + los[1] ** 2 + los[2] ** 2)
    bore_norm = xp.sqrt(bore[0] ** 2 + bore[1] ** 2 + bore[2] ** 2)
    los_body = [
        sum(xp.entry(attitude_matrix, i, j) * los[j] for j in range(3)) / los_norm for i in range(3)
    ]
    unit_bore = [b / bore_norm for b in bore]
    cos_alpha = sum(lb * b for lb, b in zip(los_body, unit_bore, strict=True))
    versine = 0.5 * sum((lb - b) ** 2 for lb, b in zip(los_body, unit_bore, strict=True))
    return cos_alpha, versine


def snr_db(
    attitude_matrix: Any,
    los_orbit: Any,
    boresight_body: Any,
    p0_dbw: Any,
    noise_dbw: Any,
    pattern: Pattern,
    antenna: Any = None,
) -> Any:
    """Noise-free SNR (dB), ``G(alpha) + 10 lg P0 - 10 lg P_n`` (Liu et al. 2023 eqs. 4, 13).

    The single definition of the model for numpy and CasADi inputs (shapes as
    in :func:`off_boresight`; ``p0_dbw``, ``noise_dbw`` and ``antenna`` broadcast
    against the per-observation shape; ``antenna`` only with an
    :class:`~attopt.formulations.gain_patterns.AntennaPatterns`).  numpy inputs are checked:
    :class:`InvalidObservationError` if any line of sight or boresight is
    NaN/inf or zero, the attitude is not a rotation, a power is not finite, or
    an observation lies outside the pattern's main lobe
    (:func:`observation_mask` finds them in a batch).
    """
    xp = namespace_of(attitude_matrix, los_orbit, boresight_body, p0_dbw, noise_dbw)
    if xp is NUMPY:
        attitude_matrix, los_orbit, boresight_body = _numpy_inputs(
            attitude_matrix, los_orbit, boresight_body
        )
    with np.errstate(invalid="ignore", divide="ignore"):
        cos_alpha, versine = off_boresight(attitude_matrix, los_orbit, boresight_body)
    if xp is NUMPY:
        if not (np.all(np.isfinite(p0_dbw)) and np.all(np.isfinite(noise_dbw))):
            raise InvalidObservationError("isotropic or noise power is NaN/inf")
        reasons = _invalid_reasons(
            attitude_matrix, los_orbit, boresight_body, cos_alpha, pattern, antenna
        )
        _raise_if_invalid(reasons)
    return _gain_dbi(pattern, cos_alpha, versine, antenna, xp) + p0_dbw - noise_dbw


def snr_db_or_nan(
    attitude_matrix: ArrayLike,
    los_orbit: ArrayLike,
    boresight_body: ArrayLike,
    p0_dbw: ArrayLike,
    noise_dbw: ArrayLike,
    pattern: Pattern,
    antenna: ArrayLike | None = None,
    rotations: bool = False,
) -> Array:
    """:func:`snr_db` (numpy) with NaN, instead of the exception, for each observation
    :func:`observation_mask` rejects; the geometry and the checks evaluated once
    (``rotations``: the matrices come from a ``scipy`` ``Rotation``, and only their
    finiteness is checked).

    Example::

        >>> import numpy as np
        >>> from attopt.formulations.gain_patterns import LIU2023_HELIX
        >>> los = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]])  # on and behind the boresight
        >>> snr_db_or_nan(np.eye(3), los, [0.0, 0.0, 1.0], 30.0, 0.0, LIU2023_HELIX).round(2)
        array([41.6,  nan])
    """
    if not (np.all(np.isfinite(p0_dbw)) and np.all(np.isfinite(noise_dbw))):
        raise InvalidObservationError("isotropic or noise power is NaN/inf")
    a, los, bore = _numpy_inputs(attitude_matrix, los_orbit, boresight_body)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos_alpha, versine = off_boresight(a, los, bore)
        reasons = _invalid_reasons(a, los, bore, cos_alpha, pattern, antenna, rotations)
        bad = np.logical_or.reduce([rejected for _, rejected in reasons])
        # rejected observations are evaluated on the boresight, inside every pattern's lobe
        cos_alpha, versine = np.where(bad, 1.0, cos_alpha), np.where(bad, 0.0, versine)
        gain = _gain_dbi(pattern, cos_alpha, versine, antenna, NUMPY)
    return np.where(bad, np.nan, gain + np.asarray(p0_dbw) - np.asarray(noise_dbw))


def _gain_dbi(pattern: Pattern, cos_alpha: Any, versine: Any, antenna: Any, xp: Any) -> Any:
    if isinstance(pattern, AntennaPatterns):
        return pattern.gain_dbi(cos_alpha, versine, antenna, xp)
    return pattern.gain_dbi(cos_alpha, versine, xp)


def observation_mask(
    attitude_matrix: ArrayLike,
    los_orbit: ArrayLike,
    boresight_body: ArrayLike,
    pattern: Pattern,
    antenna: ArrayLike | None = None,
) -> NDArray[np.bool_]:
    """``(..., m)`` mask of observations :func:`snr_db` accepts (numpy, vectorised).

    False where the line of sight or boresight is NaN/inf or zero, the
    attitude is not a finite rotation, or ``cos(alpha)`` is below the ``min_cos``
    of the observation's pattern.
    """
    a, los, bore = _numpy_inputs(attitude_matrix, los_orbit, boresight_body)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos_alpha, _ = off_boresight(a, los, bore)
    reasons = _invalid_reasons(a, los, bore, cos_alpha, pattern, antenna)
    return ~np.logical_or.reduce([bad for _, bad in reasons])


def _numpy_inputs(
    attitude_matrix: ArrayLike, los_orbit: ArrayLike, boresight_body: ArrayLike
) -> tuple[Array, Array, Array]:
    a = np.asarray(attitude_matrix, dtype=float)
    los = np.asarray(los_orbit, dtype=float)
    bore = np.asarray(boresight_body, dtype=float)
    try:
        if a.shape[-2:] != (3, 3) or los.shape[-1:] != (3,) or bore.shape[-1:] != (3,):
            raise ValueError
        np.broadcast_shapes((*a.shape[:-2], 1), los.shape[:-1], bore.shape[:-1])
    except ValueError:
        raise InvalidObservationError(
            f"expected (..., 3, 3) attitude and (..., m, 3) vectors that broadcast, got shapes "
            f"{a.shape}, {los.shape}, {bore.shape}"
        ) from None
    return a, los, bore


def _invalid_reasons(
    a: Array,
    los: Array,
    bore: Array,
    cos_alpha: Array,
    pattern: Pattern,
    antenna: Any = None,
    rotations: bool = False,
) -> list[tuple[str, NDArray[np.bool_]]]:
    """Each reason to reject an observation and where it applies.  ``rotations``: the
    matrices ``a`` come from a ``scipy`` ``Rotation`` (orthonormal, determinant 1, by
    construction), so only their finiteness is checked: the orthogonality test costs a
    matrix product and a determinant per observation, most of a pass's check."""
    with np.errstate(invalid="ignore"):
        if rotations:
            is_rotation = np.isfinite(a).all(axis=(-2, -1))
        else:
            orthogonality = np.abs(a @ np.swapaxes(a, -1, -2) - np.eye(3)).max(axis=(-2, -1))
            is_rotation = (orthogonality < _ROTATION_TOLERANCE) & (np.linalg.det(a) > 0)
    shape = np.shape(cos_alpha)
    reasons = [
        ("line of sight is NaN/inf or zero", ~_finite_nonzero(los)),
        ("boresight is NaN/inf or zero", ~_finite_nonzero(bore)),
        (
            "attitude is NaN/inf or not a rotation",
            ~is_rotation[..., None],
        ),
        _beyond_lobe(cos_alpha, pattern, antenna),
    ]
    return [(reason, np.broadcast_to(bad, shape)) for reason, bad in reasons]


def _beyond_lobe(cos_alpha: Array, pattern: Pattern, antenna: Any) -> tuple[str, NDArray[np.bool_]]:
    if isinstance(pattern, AntennaPatterns):
        return (
            "off-boresight angle beyond the main lobe of the receiving antenna",
            ~(cos_alpha >= pattern.min_cos(antenna)),
        )
    return (
        f"off-boresight angle beyond the main lobe "
        f"({np.degrees(pattern.max_off_boresight_rad):.2f} deg)",
        ~(cos_alpha >= pattern.min_cos),
    )


def _finite_nonzero(vectors: Array) -> NDArray[np.bool_]:
    return np.isfinite(vectors).all(axis=-1) & np.any(vectors != 0, axis=-1)


def _raise_if_invalid(reasons: list[tuple[str, NDArray[np.bool_]]]) -> None:
    for reason, bad in reasons:
        if bad.any():
            first = tuple(int(i) for i in np.argwhere(bad)[0])
            raise InvalidObservationError(
                f"{int(bad.sum())} invalid observation(s): {reason} (first at index {first})"
            )


def symbolic_inputs(pattern: Pattern, m: int) -> list[ca.SX]:
    """The symbols of the per-epoch inputs of the compiled SNR functions: lines of sight
    ``m x 3``, boresight rows ``m x 3``, ``p0`` ``(m)``, noise power, and with an
    :class:`~attopt.formulations.gain_patterns.AntennaPatterns` the receiving antenna
    ``(m)``; :func:`input_names` names them."""
    if m < 1:
        raise InvalidObservationError(f"need at least one observation, got m = {m}")
    inputs = [
        ca.SX.sym("los_orbit", m, 3),
        ca.SX.sym("boresight_body", m, 3),
        ca.SX.sym("p0_dbw", m),
        ca.SX.sym("noise_dbw"),
    ]
    if isinstance(pattern, AntennaPatterns):
        inputs.append(ca.SX.sym("antenna", m))
    return inputs


def input_names(pattern: Pattern) -> list[str]:
    """Names of :func:`symbolic_inputs`."""
    names = ["los_orbit", "boresight_body", "p0_dbw", "noise_dbw"]
    return [*names, "antenna"] if isinstance(pattern, AntennaPatterns) else names


def _symbolic_snr(pattern: Pattern, m: int) -> tuple[list[ca.SX], ca.SX]:
    v, attitude_ref = ca.SX.sym("v", 3), ca.SX.sym("attitude_ref", 3, 3)
    data = symbolic_inputs(pattern, m)
    snr = pattern_snr_model(pattern)(increment_matrix(v) @ attitude_ref, *data)
    return [v, attitude_ref, *data], snr


@lru_cache(maxsize=16)
def pattern_snr_model(pattern: Pattern) -> Callable[..., Any]:
    """:func:`snr_db` with ``pattern`` bound, a model for :func:`attitude_model_function`
    (arguments: attitude, lines of sight, boresights, ``p0``, noise power, and with an
    :class:`~attopt.formulations.gain_patterns.AntennaPatterns` the receiving antennas)."""
    if isinstance(pattern, AntennaPatterns):

        def antenna_snr_model(
            attitude: Any, los: Any, boresight: Any, p0: Any, noise: Any, antenna: Any
        ) -> Any:
            return snr_db(attitude, los, boresight, p0, noise, pattern, antenna)

        return antenna_snr_model

    def snr_model(attitude: Any, los: Any, boresight: Any, p0: Any, noise: Any) -> Any:
        return snr_db(attitude, los, boresight, p0, noise, pattern)

    return snr_model


@lru_cache(maxsize=64)
def snr_function(pattern: Pattern, m: int) -> ca.Function:
    """``(v[3], A_ref[3x3], los[m x 3], boresight[m x 3], p0[m], noise[, antenna[m]]) ->
    snr[m]``.

    CasADi function of :func:`snr_db` at the attitude ``C(v) A_ref``
    (:func:`increment_matrix`); boresight row ``i`` (and ``antenna`` entry ``i``)
    is the antenna that received observation ``i``.  Inputs are not checked (use
    :func:`observation_mask`).
    """
    inputs, snr = _symbolic_snr(pattern, m)
    names = ["v", "attitude_ref", *input_names(pattern)]
    return ca.Function("snr", inputs, [snr], names, ["snr_db"])


@lru_cache(maxsize=64)
def snr_jacobian_function(pattern: Pattern, m: int) -> ca.Function:
    """As :func:`snr_function`, returning ``(snr[m], d snr / d v [m x 3])`` by CasADi AD."""
    inputs, snr = _symbolic_snr(pattern, m)
    jacobian = ca.jacobian(snr, inputs[0])
    names = ["v", "attitude_ref", *input_names(pattern)]
    return ca.Function("snr_jacobian", inputs, [snr, jacobian], names, ["snr_db", "jac_v"])


def predict_snr(
    attitude: Rotation,
    los_orbit: ArrayLike,
    boresight_body: ArrayLike,
    p0_dbw: ArrayLike,
    noise_dbw: ArrayLike,
    pattern: Pattern,
    mask: ArrayLike | str | None = None,
    model: Callable[..., Any] | None = None,
    antenna: ArrayLike | None = None,
) -> tuple[Array, Array]:
    """Predicted SNR ``(..., m)`` and its Jacobian ``(..., m, 3)`` (dB/rad), numpy.

    The Jacobian is with respect to the body-frame rotation-vector error
    ``delta`` of ``exp(delta) A`` at ``delta = 0`` (``docs/conventions.md``),
    evaluated by CasADi AD of the model at ``C(v) A``, ``v = 0``
    (:func:`attopt.formulations.attitude_model.attitude_model_function`; ``C(v)``
    and ``exp(v)`` agree to first order), one observation per mapped call.  ``attitude`` is one
    rotation or a stack of ``N``; arrays broadcast as in :func:`snr_db`.
    Observations where ``mask`` is False are not evaluated (NaN values and
    Jacobian rows); all others must be valid, else
    :class:`InvalidObservationError`; ``mask="valid"`` evaluates exactly the
    valid ones (:func:`observation_mask`) and leaves the rest NaN.
    ``model`` replaces :func:`snr_db` (same arguments, pattern bound) by a
    function of it, e.g. the truncated mean of :mod:`attopt.formulations.snr_measurement`.
    ``antenna`` (broadcasting against ``(..., m)``) is each observation's receiving
    antenna, needed with an :class:`~attopt.formulations.gain_patterns.AntennaPatterns`.
    """
    a, los, bore = _numpy_inputs(attitude.as_matrix(), los_orbit, boresight_body)
    offset = np.asarray(p0_dbw, dtype=float) - np.asarray(noise_dbw, dtype=float)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos_alpha, _ = off_boresight(a, los, bore)
    shape = np.broadcast_shapes(np.shape(cos_alpha), offset.shape)
    per_antenna = isinstance(pattern, AntennaPatterns)
    if per_antenna:
        antenna = np.broadcast_to(np.asarray(antenna, dtype=np.intp), shape)
    reasons = _invalid_reasons(
        a, los, bore, np.broadcast_to(cos_alpha, shape), pattern, antenna, rotations=True
    )
    reasons.append(
        ("isotropic or noise power is NaN/inf", ~np.isfinite(np.broadcast_to(offset, shape)))
    )
    if isinstance(mask, str) and mask == "valid":
        use = ~np.logical_or.reduce([bad for _, bad in reasons])
    else:
        use = (
            np.ones(shape, bool) if mask is None else np.broadcast_to(np.asarray(mask, bool), shape)
        )
        _raise_if_invalid([(reason, bad & use) for reason, bad in reasons])

    rows = int(np.prod(shape))
    if rows == 0:
        return np.empty(shape), np.empty((*shape, 3))
    # One observation per row; unused ones are replaced by one on the boresight.
    use_k = use.reshape(rows, 1)
    a = np.broadcast_to(a[..., None, :, :], (*shape, 3, 3)).reshape(rows, 3, 3)
    filler = np.array([0.0, 0.0, 1.0])
    bore = np.where(use_k, np.broadcast_to(bore, (*shape, 3)).reshape(rows, 3), filler)
    los_filler = filler @ a  # A^T b: along the boresight
    los = np.where(use_k, np.broadcast_to(los, (*shape, 3)).reshape(rows, 3), los_filler)
    offset = np.where(use, np.broadcast_to(offset, shape), 0.0).reshape(rows)
    shapes = ((1, 3), (1, 3), (1, 1), (1, 1))
    extra = (antenna.reshape(rows),) if per_antenna else ()
    snr, jac = evaluate_at_attitudes(
        attitude_model_function(
            model or pattern_snr_model(pattern), shapes + ((1, 1),) * len(extra)
        ),
        a,
        los,
        bore,
        offset,
        0.0,
        *extra,
    )
    snr = snr.reshape(shape)
    jac = jac.reshape(*shape, 3)
    snr[~use] = np.nan
    jac[~use] = np.nan
    return snr, jac


def fisher_information(
    jacobian: ArrayLike, sigma_db: ArrayLike = SNR_SIGMA_DB, mask: ArrayLike | None = None
) -> Array:
    """``F = sum_i J_i^T J_i / sigma_i^2`` (rad^-2, body frame), Liu et al. 2023 eq. 22.

    ``jacobian`` is ``(..., m, 3)`` from :func:`predict_snr`; ``sigma_db``
    broadcasts against ``(..., m)``; rows where ``mask`` is False are left out.
    """
    jac = np.asarray(jacobian, dtype=float)
    weight = np.broadcast_to(np.asarray(sigma_db, dtype=float) ** -2, jac.shape[:-1])
    if mask is not None:
        use = np.broadcast_to(np.asarray(mask, bool), jac.shape[:-1])
        jac = np.where(use[..., None], jac, 0.0)
        weight = np.where(use, weight, 0.0)
    return np.einsum("...mi,...m,...mj->...ij", jac, weight, jac)


def cramer_rao_bound(fisher: ArrayLike, rtol: float = 1e-10) -> Array:
    """Cramer-Rao bound ``F^-1`` (rad^2, body frame), infinite where unobservable.

    Defined as the entrywise limit of ``(F + eps I)^-1`` as ``eps -> 0+``.
    With ``F = V diag(lambda) V^T``, eigenvalues ``lambda <= rtol lambda_max``
    span the unobservable subspace with projector ``Pi``; entries where
    ``|Pi| > 1e-9`` are ``sign(Pi) inf`` (so the diagonal is ``+inf`` on every
    body axis the unobservable rotation moves, e.g. the boresight axis when
    all observations come from one antenna, Liu et al. 2023 sec. 3.1), the others
    are those of the inverse on the observable subspace.
    """
    eigenvalues, vectors, null = _null_space(fisher, rtol)
    inverse = np.where(null, 0.0, 1.0 / np.where(null, 1.0, eigenvalues))
    observable = np.einsum("...ik,...k,...jk->...ij", vectors, inverse, vectors)
    projector = np.einsum("...ik,...k,...jk->...ij", vectors, null.astype(float), vectors)
    unbounded = np.abs(projector) > _NULL_PROJECTOR_TOLERANCE
    return np.where(unbounded, np.copysign(np.inf, projector), observable)


def unobservable_directions(
    fisher: ArrayLike, rtol: float = 1e-10
) -> tuple[NDArray[np.intp], Array]:
    """The rotations the data cannot see: the dimension ``(...)`` of the unobservable
    subspace of each Fisher information (the null space of :func:`cramer_rao_bound`) and,
    where it is one-dimensional, its unit direction ``(..., 3)`` in the body frame (sign:
    largest component positive; NaN elsewhere).

    With every observation from one antenna it is that antenna's boresight (Liu et al. 2023
    sec. 3.1): the body axes on which the bound is infinite are those the boresight has a
    component on, while the direction itself says which rotation is unseen.

    Example::

        >>> import numpy as np
        >>> count, direction = unobservable_directions(np.diag([2.0, 1.0, 0.0]))
        >>> int(count), direction.tolist()
        (1, [0.0, 0.0, 1.0])
    """
    _, vectors, null = _null_space(fisher, rtol)
    count = null.sum(axis=-1)
    first = np.take_along_axis(vectors, np.argmax(null, axis=-1)[..., None, None], axis=-1)[..., 0]
    largest = np.take_along_axis(first, np.argmax(np.abs(first), axis=-1)[..., None], axis=-1)
    direction = first * np.sign(largest)
    return count, np.where((count == 1)[..., None], direction, np.nan)


def _null_space(fisher: ArrayLike, rtol: float) -> tuple[Array, Array, NDArray[np.bool_]]:
    """Eigenvalues (ascending), eigenvectors (columns) of the symmetrised ``fisher``, and
    which eigenvalues are at most ``rtol`` times the largest (the unobservable subspace)."""
    f = np.asarray(fisher, dtype=float)
    eigenvalues, vectors = np.linalg.eigh(0.5 * (f + np.swapaxes(f, -1, -2)))
    return eigenvalues, vectors, eigenvalues <= rtol * eigenvalues[..., -1:]
