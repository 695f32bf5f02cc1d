"""Exceptions raised for bad input or failed solves.

Every solver raises one of these (or returns a result flagged invalid with the
reason) instead of returning a silently wrong attitude.
"""


class AttoptError(Exception):
    """Base class of every error attopt raises on purpose."""


class InvalidObservationError(AttoptError, ValueError):
    """The input is malformed: wrong shape, NaN/inf, zero-length vector, bad weight."""


class UnobservableError(AttoptError):
    """The input is well formed but does not determine the attitude.

    Examples: fewer than two vector observations, or all observed directions
    (anti)parallel so that the rotation about them is unobservable.
    """


class ConvergenceError(AttoptError):
    """An iterative or convex solver did not reach its optimum."""


class ModelMismatchError(AttoptError):
    """The measurements contradict their model at the estimate: its residuals fail the
    chi-square test of the noise the model assumes, so its covariance cannot be trusted
    (e.g. transmitter power offsets the SNR model does not have)."""


class GyroRateMismatchError(InvalidObservationError):
    """A gyro record's sample spacing differs from the rate its model declares."""


class UnsupportedMeasurementError(AttoptError, TypeError):
    """An estimator was given a measurement type it does not accept (see its ``accepts``)."""
