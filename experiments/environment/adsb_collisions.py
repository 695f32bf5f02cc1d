"""Collisions of 1090ES (ADS-B) messages at a LEO receiver, with a power-capture rule.

Liu et al. 2023 assume every message above the reception threshold is received.  A LEO
receiver sees hundreds to thousands of aircraft at once, and their messages overlap.

Traffic.  Each aircraft sends extended squitters at ``lambda = 6.2`` messages per second
on average (:data:`SQUITTER_RATE_HZ`), each ``T = 120 us`` long (8 us preamble + 112 us
data, :data:`MESSAGE_DURATION_S`).  Real squitters are jittered periodic (each type at
its own nominal interval with a random jitter); the message times of each aircraft are
modelled here as an independent Poisson process of rate ``lambda``, the standard model of
space-based ADS-B collision studies (pure ALOHA, e.g. Van der Pryt and Vincent 2015).
A transponder never overlaps itself, so an aircraft's own messages do not interfere
with each other.

Overlap.  Message ``i`` (start ``t_i``) overlaps message ``j`` of another aircraft iff
``|t_i - t_j| < T``: the vulnerable period is ``2 T``.  Among ``N`` other transmitters
the number of overlapping messages is ``K ~ Poisson(mu)``, ``mu = 2 T lambda N``, and

    P(no overlap) = exp(-2 T lambda N).

Capture (:class:`CaptureRule`).  With ``P_i`` the received power (linear) of message
``i`` and ``I_i = sum_j P_j`` over every message overlapping it, ``i`` survives iff

    10 lg(P_i / I_i) >= capture_margin_db        (or no message overlaps it),

so that, with ``q_k(P) = Pr(P >= m sum_{j=1..k} X_j)`` (``m = 10^(margin/10)``, ``X_j``
independent interferer powers), the reception probability of a message of power ``P`` is

    P(survive | P) = sum_k Poisson(k; mu) q_k(P),   q_0 = 1.

Variant ``leading_only``: a receiver that does not re-trigger on a later preamble
decodes only a message that arrives before all its overlapping messages; then no
interferer may start in ``(t_i - T, t_i]`` and ``K`` counts those in ``(t_i, t_i + T)``:

    P(survive | P) = exp(-T lambda N) sum_k Poisson(k; T lambda N) q_k(P).

Ideal (``collisions = False``): every message survives, as in Liu et al. 2023.

Only power ratios enter the rule, so powers may be given in any common dB reference
(received power in dBW, or SNR in dB against one noise power).  Receiver noise is not
part of the rule: the reception threshold on the SNR is applied separately.  Every
aircraft in view interferes, including those below the reception threshold.

Run ``python -m attopt.experiments.environment.adsb_collisions --out
docs/figures/adsb_collisions.png`` for the figure and table of ``docs/adsb_collisions.md``.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import Field, field_validator
from scipy import stats

from attopt.experiments.config import Parameters
from attopt.experiments.environment.traffic import MEAN_RADIUS_KM
from attopt.formulations.link_budget import LinkBudget

SQUITTER_RATE_HZ = 6.2
"""Mean squitter rate of one aircraft (messages per second), the figure usually quoted
for the 1090 MHz load of an ADS-B aircraft (airborne position and velocity at 2 per
second each, identification at 0.2, plus status and acquisition squitters); every
message is modelled as a 120 us extended squitter."""
MESSAGE_DURATION_S = 120e-6
"""Length of one 1090ES message: 8 us preamble + 112 us (112 bits at 1 Mbit/s)."""
DEFAULT_CAPTURE_MARGIN_DB = 4.0
"""Default capture margin (:class:`CaptureRule`)."""


class CaptureRule(Parameters):
    """How overlapping messages are resolved at the receiver (module docstring).

    ``capture_margin_db`` is the margin by which a message's power must exceed the summed
    power of every message overlapping it.  The default, 4 dB, lies in the range of a
    few dB (about 3 to 6 dB) assumed for the capture of 1090 MHz Mode S / 1090ES
    receivers; it depends on the demodulator and no single value is standard, so it is
    a parameter.  ``inf`` is a receiver without
    capture (every overlapped message is lost); ``-inf`` keeps every message.

    The default is power capture regardless of arrival order (``leading_only = False``),
    the cumulative-interference capture model of random-access channels (Zorzi and
    Rao 1994), which describes a receiver that re-triggers on the preamble of a
    stronger later message.  ``leading_only = True`` is a receiver without re-triggering.
    """

    collisions: bool = Field(
        True, description="Whether messages collide (False: every message survives)."
    )
    capture_margin_db: float = Field(
        DEFAULT_CAPTURE_MARGIN_DB,
        description="Power over the summed overlapping power a message needs to survive.",
    )
    leading_only: bool = Field(
        False, description="Whether only a message arriving before all overlapping ones survives."
    )

    @field_validator("capture_margin_db")
    @classmethod
    def _not_nan(cls, margin_db: float) -> float:
        if math.isnan(margin_db):
            raise ValueError("capture_margin_db must not be NaN")
        return margin_db

    @property
    def margin_ratio(self) -> float:
        """``m = 10^(capture_margin_db / 10)`` (0 for ``-inf``, ``inf`` for ``inf``)."""
        return 10.0 ** (self.capture_margin_db / 10.0)


NO_COLLISIONS = CaptureRule(collisions=False)
"""The ideal receiver of Liu et al. 2023: no message is lost to collisions."""
NO_CAPTURE = CaptureRule(capture_margin_db=math.inf)
"""Pure collisions: every overlapped message is lost."""


def vulnerable_mean(
    n_others: ArrayLike,
    rate_hz: float = SQUITTER_RATE_HZ,
    duration_s: float = MESSAGE_DURATION_S,
) -> NDArray[np.float64]:
    """``mu = 2 T lambda N``: mean number of messages of ``N`` other transmitters
    overlapping one message (vulnerable period ``2 T``)."""
    return 2.0 * duration_s * rate_hz * np.asarray(n_others, dtype=float)


def no_overlap_probability(
    n_others: ArrayLike,
    rate_hz: float = SQUITTER_RATE_HZ,
    duration_s: float = MESSAGE_DURATION_S,
) -> NDArray[np.float64]:
    """``exp(-2 T lambda N)``: probability that no message overlaps a given one."""
    return np.exp(-vulnerable_mean(n_others, rate_hz, duration_s))


def capture_probabilities(
    power_db: ArrayLike,
    interferer_powers_db: ArrayLike,
    k_max: int,
    margin_ratio: float,
    rng: np.random.Generator,
    n_draws: int = 20_000,
) -> NDArray[np.float64]:
    """``q_k(P) = Pr(P >= m sum_{j=1..k} X_j)`` for ``k = 0..k_max``, shape
    ``(len(power_db), k_max + 1)``.

    ``X_j`` are drawn independently from the empirical distribution of
    ``interferer_powers_db``.  ``q_0 = 1``; ``q_1(P)`` is exact (the empirical
    distribution function of ``X`` at ``P / m``); for ``k >= 2`` it is Monte Carlo:
    ``n_draws`` rows of ``k_max`` draws, whose running sums give the ``k``-interferer
    sums of every ``k`` from the same rows (so ``q_k`` does not increase with ``k``),
    with standard error at most ``0.5 / sqrt(n_draws)``.
    """
    power = 10.0 ** (np.atleast_1d(np.asarray(power_db, dtype=float)) / 10.0)
    sample = np.sort(10.0 ** (np.asarray(interferer_powers_db, dtype=float).ravel() / 10.0))
    with np.errstate(divide="ignore"):
        threshold = power / margin_ratio
    q = np.ones((power.size, k_max + 1))
    if k_max >= 1:
        q[:, 1] = np.searchsorted(sample, threshold, side="right") / sample.size
    if k_max >= 2:
        draws = sample[rng.integers(sample.size, size=(n_draws, k_max))]
        sums = np.sort(np.cumsum(draws, axis=1)[:, 1:], axis=0)
        for k in range(2, k_max + 1):
            q[:, k] = np.searchsorted(sums[:, k - 2], threshold, side="right") / n_draws
    return q


def reception_probability(
    power_db: ArrayLike,
    interferer_powers_db: ArrayLike,
    n_others: int,
    rule: CaptureRule,
    rng: np.random.Generator,
    *,
    rate_hz: float = SQUITTER_RATE_HZ,
    duration_s: float = MESSAGE_DURATION_S,
    n_draws: int = 20_000,
    tail: float = 1e-12,
) -> NDArray[np.float64]:
    """Analytic ``P(survive | P)`` of a message of each power in ``power_db`` among
    ``n_others`` transmitters whose powers follow ``interferer_powers_db``.

    ``sum_k Poisson(k; mu) q_k(P)`` with ``mu = 2 T lambda N``, or, for
    ``rule.leading_only``, ``exp(-mu/2) sum_k Poisson(k; mu/2) q_k(P)`` (module
    docstring); ``q_k`` from :func:`capture_probabilities`.  The sum stops at the
    ``k_max`` above which the Poisson tail is below ``tail``; the terms ``k >= k_max``
    are lumped into one with ``q_k_max`` (exact for ``q`` constant in ``k``, a lower
    bound otherwise, since ``q_k`` does not increase with ``k``).
    """
    power = np.atleast_1d(np.asarray(power_db, dtype=float))
    if not rule.collisions:
        return np.ones(power.size)
    mu = float(vulnerable_mean(n_others, rate_hz, duration_s))
    scale = 1.0
    if rule.leading_only:
        mu *= 0.5
        scale = math.exp(-mu)
    k_max = int(stats.poisson.isf(tail, mu)) if mu > 0.0 else 0
    q = capture_probabilities(power, interferer_powers_db, k_max, rule.margin_ratio, rng, n_draws)
    weights = stats.poisson.pmf(np.arange(k_max + 1), mu)
    weights[-1] = stats.poisson.sf(k_max - 1, mu)
    return scale * (q @ weights)


@dataclass(frozen=True)
class Messages:
    """Messages started in a simulated window, in time order."""

    aircraft: NDArray[np.int64]
    """Index of the sending aircraft (into the array of powers)."""
    time_s: NDArray[np.float64]
    """Start time from the start of the window."""
    survives: NDArray[np.bool_]
    """Whether the message survives collisions (:class:`CaptureRule`)."""


def draw_messages(
    n_aircraft: int,
    window_s: float,
    rng: np.random.Generator,
    rate_hz: float = SQUITTER_RATE_HZ,
    pad_s: float = MESSAGE_DURATION_S,
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Poisson message times of ``n_aircraft`` over ``[-pad_s, window_s + pad_s)``:
    ``Poisson(rate (window + 2 pad))`` messages per aircraft at uniform times, sorted by
    time.  Returns ``(aircraft, time_s)``."""
    span = window_s + 2.0 * pad_s
    counts = rng.poisson(rate_hz * span, size=n_aircraft)
    aircraft = np.repeat(np.arange(n_aircraft), counts)
    time_s = rng.uniform(-pad_s, window_s + pad_s, size=aircraft.size)
    order = np.argsort(time_s, kind="stable")
    return aircraft[order], time_s[order]


def window_neighbours(
    key: NDArray[np.float64], power: NDArray[np.float64], half_width: float
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64]]:
    """For each entry of the sorted ``key``, the entries ``j != i`` with
    ``|key_j - key_i| < half_width``: how many lie before it (lower index), how many after
    it, and the sum of their ``power`` (by prefix sums, clipped at 0)."""
    lo = np.searchsorted(key, key - half_width, side="right")
    hi = np.searchsorted(key, key + half_width, side="left")
    index = np.arange(key.size)
    prefix = np.concatenate(([0.0], np.cumsum(power)))
    total = np.maximum(prefix[hi] - prefix[lo] - power, 0.0)
    return index - lo, hi - index - 1, total


def other_aircraft_neighbours(
    aircraft: NDArray[np.int64],
    time_s: NDArray[np.float64],
    power: NDArray[np.float64],
    duration_s: float,
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64]]:
    """:func:`window_neighbours` of time-sorted messages, counting only other aircraft's.

    The own-aircraft neighbours are those of the key ``a L + t`` (``L`` longer than the
    time span plus ``T``, so keys of different aircraft are never within ``T``) and are
    subtracted.  Returns ``(n_earlier, n_later, interference)``.
    """
    span = float(time_s[-1] - time_s[0]) if time_s.size else 0.0
    key = aircraft * (span + 2.0 * duration_s) + time_s
    by_aircraft = np.argsort(key, kind="stable")
    own = window_neighbours(key[by_aircraft], power[by_aircraft], duration_s)
    n_earlier, n_later, interference = window_neighbours(time_s, power, duration_s)
    own_earlier, own_later, own_power = (np.empty_like(x) for x in own)
    own_earlier[by_aircraft], own_later[by_aircraft], own_power[by_aircraft] = own
    return (
        n_earlier - own_earlier,
        n_later - own_later,
        np.maximum(interference - own_power, 0.0),
    )


def apply_capture(
    aircraft: NDArray[np.int64],
    time_s: NDArray[np.float64],
    power_db: NDArray[np.float64],
    rule: CaptureRule,
    duration_s: float = MESSAGE_DURATION_S,
) -> NDArray[np.bool_]:
    """Whether each of the time-sorted messages survives: no message of another aircraft
    overlaps it (``|t_i - t_j| < T``), or ``P_i >= m I_i`` (and, for
    ``rule.leading_only``, none of the overlapping ones starts before it)."""
    if not rule.collisions:
        return np.ones(time_s.size, dtype=bool)
    power = 10.0 ** (power_db / 10.0)
    n_earlier, n_later, interference = other_aircraft_neighbours(
        aircraft, time_s, power, duration_s
    )
    alone = (n_earlier + n_later) == 0
    with np.errstate(invalid="ignore"):
        captures = power >= rule.margin_ratio * interference
    if rule.leading_only:
        captures &= n_earlier == 0
    return alone | captures


def simulate_messages(
    power_db: ArrayLike,
    rule: CaptureRule,
    rng: np.random.Generator,
    *,
    window_s: float = 1.0,
    rate_hz: float = SQUITTER_RATE_HZ,
    duration_s: float = MESSAGE_DURATION_S,
) -> Messages:
    """Monte Carlo of one window: each aircraft (received power ``power_db[a]``, any dB
    reference) sends Poisson messages; collisions are resolved by ``rule``.

    Messages are drawn over ``[-T, window + T)`` so that those starting in
    ``[0, window)``, the ones returned, have every possible overlap simulated.
    """
    power = np.asarray(power_db, dtype=float)
    aircraft, time_s = draw_messages(power.size, window_s, rng, rate_hz, duration_s)
    survives = apply_capture(aircraft, time_s, power[aircraft], rule, duration_s)
    inside = (time_s >= 0.0) & (time_s < window_s)
    return Messages(aircraft[inside], time_s[inside], survives[inside])


def surviving_message_counts(
    power_db: ArrayLike,
    rule: CaptureRule,
    rng: np.random.Generator,
    *,
    epoch_s: float = 1.0,
    rate_hz: float = SQUITTER_RATE_HZ,
    duration_s: float = MESSAGE_DURATION_S,
) -> NDArray[np.int64]:
    """Number of each aircraft's messages in one epoch that survive collisions.

    ``power_db``: received power (or SNR) of every aircraft in view of the receiver
    channel, those below the reception threshold included (they interfere too).  The
    counts come from :func:`simulate_messages` over the epoch, not from the analytic
    probability: the interferers are then the aircraft actually in view with their
    actual powers, and one collision decides all the messages in it together.  The
    cost is two sorts of the ``~ 6.2 N`` messages (about 7 ms for 3000 aircraft).
    An aircraft is received in the epoch iff its count is at least 1.
    """
    power = np.asarray(power_db, dtype=float)
    messages = simulate_messages(
        power, rule, rng, window_s=epoch_s, rate_hz=rate_hz, duration_s=duration_s
    )
    return np.bincount(messages.aircraft[messages.survives], minlength=power.size)


def footprint_powers_db(
    n: int,
    rng: np.random.Generator,
    altitude_km: float = 600.0,
    aircraft_height_km: float = 10.0,
    budget: LinkBudget | None = None,
) -> NDArray[np.float64]:
    """Received powers (dBW, 0 dBi receive antenna) of ``n`` aircraft uniform over the
    area of the satellite's visible cap (elevation >= 0 at the aircraft).

    With ``r_a``, ``r_s`` the aircraft and satellite radii, the cap is
    ``cos theta >= r_a / r_s`` (``theta`` the central angle), uniform in ``cos theta``;
    the slant range is ``d = sqrt(r_a^2 + r_s^2 - 2 r_a r_s cos theta)`` and the power
    ``P0(d)`` of :class:`~attopt.formulations.link_budget.LinkBudget` (Liu et al.
    2023 eq. 3).
    """
    r_a = MEAN_RADIUS_KM + aircraft_height_km
    r_s = MEAN_RADIUS_KM + altitude_km
    cos_theta = rng.uniform(r_a / r_s, 1.0, size=n)
    range_km = np.sqrt(r_a**2 + r_s**2 - 2.0 * r_a * r_s * cos_theta)
    return (budget or LinkBudget()).isotropic_power_dbw(1000.0 * range_km)


def aircraft_reception_probability(
    message_probability: ArrayLike,
    rate_hz: float = SQUITTER_RATE_HZ,
    epoch_s: float = 1.0,
) -> NDArray[np.float64]:
    """``1 - exp(-lambda tau p)``: probability that at least one of an aircraft's
    messages in an epoch of ``tau`` survives, its Poisson message stream thinned by the
    reception probability ``p`` of each message (independently, since its messages
    overlap disjoint sets of others; the approximation ignores the aircraft's
    interferers being the same across the epoch)."""
    return 1.0 - np.exp(-rate_hz * epoch_s * np.asarray(message_probability, dtype=float))


@dataclass(frozen=True)
class CurveRow:
    """Reception probabilities at one number of aircraft in view, one entry per rule."""

    n_aircraft: int
    message_analytic: tuple[float, ...]
    """:func:`reception_probability` averaged over the power distribution."""
    message_monte_carlo: tuple[float, ...]
    """Fraction of the simulated messages that survive."""
    aircraft_analytic: tuple[float, ...]
    """:func:`aircraft_reception_probability` averaged over the power distribution."""
    aircraft_monte_carlo: tuple[float, ...]
    """Fraction of the simulated aircraft-epochs with a surviving message."""


def curve_row(
    n_aircraft: int,
    rules: tuple[CaptureRule, ...],
    population_db: NDArray[np.float64],
    rng: np.random.Generator,
    min_messages: int = 30_000,
    n_powers: int = 4000,
) -> CurveRow:
    """Reception probabilities of ``n_aircraft`` aircraft whose powers follow
    ``population_db``, per rule.

    Analytic: :func:`reception_probability` of the first ``n_powers`` powers of
    ``population_db`` among ``n_aircraft - 1`` others drawn from all of it, averaged.
    Monte Carlo: ``n_aircraft`` powers drawn from ``population_db``, then
    :func:`simulate_messages` over enough 1 s epochs for ``min_messages`` messages.
    """
    epochs = max(1, math.ceil(min_messages / (SQUITTER_RATE_HZ * n_aircraft)))
    powers = rng.choice(population_db, size=n_aircraft)
    columns: list[tuple[float, float, float, float]] = []
    for rule in rules:
        p = reception_probability(
            population_db[:n_powers], population_db, n_aircraft - 1, rule, rng
        )
        sent = survived = received = 0
        for _ in range(epochs):
            messages = simulate_messages(powers, rule, rng)
            counts = np.bincount(messages.aircraft[messages.survives], minlength=n_aircraft)
            sent += messages.survives.size
            survived += int(np.sum(messages.survives))
            received += int(np.count_nonzero(counts))
        columns.append(
            (
                float(np.mean(p)),
                survived / sent,
                float(np.mean(aircraft_reception_probability(p))),
                received / (epochs * n_aircraft),
            )
        )
    message_analytic, message_mc, aircraft_analytic, aircraft_mc = zip(*columns, strict=True)
    return CurveRow(n_aircraft, message_analytic, message_mc, aircraft_analytic, aircraft_mc)


RULE_NAMES = ("no capture", "capture", "capture, leading only")


def format_table(rows: list[CurveRow]) -> str:
    """Markdown table: per rule, the analytic / Monte Carlo probability that a message
    survives, then that an aircraft has a surviving message in a 1 s epoch."""
    names = [f"message, {name}" for name in RULE_NAMES] + [
        f"aircraft in 1 s, {name}" for name in RULE_NAMES
    ]
    lines = [
        "| aircraft in view | 2 T lambda (N - 1) | " + " | ".join(names) + " |",
        "|---" * (len(names) + 2) + "|",
    ]
    for row in rows:
        pairs = zip(
            row.message_analytic + row.aircraft_analytic,
            row.message_monte_carlo + row.aircraft_monte_carlo,
            strict=True,
        )
        cells = " | ".join(f"{a:.4f} / {m:.4f}" for a, m in pairs)
        mu = float(vulnerable_mean(row.n_aircraft - 1))
        lines.append(f"| {row.n_aircraft} | {mu:.3f} | {cells} |")
    return "\n".join(lines)


def plot_curves(
    rows: list[CurveRow],
    rules: tuple[CaptureRule, ...],
    population_db: NDArray[np.float64],
    out: Path,
    rng: np.random.Generator,
    n_powers: int = 4000,
) -> None:
    """Analytic curves (lines, as in :func:`curve_row`) and Monte Carlo points of the
    message reception probability against the number of aircraft in view (log scale),
    written to ``out``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = np.unique(np.geomspace(10, 5000, 60).astype(int))
    messages_db = population_db[:n_powers]
    fig, ax = plt.subplots(figsize=(7.0, 4.5))
    for i, (rule, name) in enumerate(zip(rules, RULE_NAMES, strict=True)):
        curve = [
            np.mean(reception_probability(messages_db, population_db, k - 1, rule, rng)) for k in n
        ]
        (line,) = ax.plot(n, curve, label=f"{name} (analytic)")
        ax.plot(
            [r.n_aircraft for r in rows],
            [r.message_monte_carlo[i] for r in rows],
            "o",
            color=line.get_color(),
            label=f"{name} (Monte Carlo)",
        )
    ax.set_xscale("log")
    ax.set_xlabel("aircraft in view N")
    ax.set_ylabel("message reception probability")
    ax.set_ylim(0.0, 1.02)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    margin = rules[1].capture_margin_db
    ax.set_title(f"1090ES collisions at a 600 km receiver (capture margin {margin:g} dB)")
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=150, bbox_inches="tight")
    plt.close(fig)


GRID = (10, 30, 100, 300, 1000, 2000, 3000, 5000)
"""Numbers of aircraft in view of the table and the Monte Carlo points."""


def main(argv: list[str] | None = None) -> list[CurveRow]:
    """Table (printed) and figure of reception probability against aircraft in view."""
    parser = argparse.ArgumentParser(description=main.__doc__)
    parser.add_argument("--out", type=Path, default=Path("docs/figures/adsb_collisions.png"))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--margin-db", type=float, default=DEFAULT_CAPTURE_MARGIN_DB)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    rules = (
        NO_CAPTURE,
        CaptureRule(capture_margin_db=args.margin_db),
        CaptureRule(capture_margin_db=args.margin_db, leading_only=True),
    )
    population_db = footprint_powers_db(100_000, rng)
    rows = [curve_row(n, rules, population_db, rng) for n in GRID]
    print(format_table(rows))
    plot_curves(rows, rules, population_db, args.out, rng)
    print(f"figure: {args.out}")
    return rows


if __name__ == "__main__":
    main()
