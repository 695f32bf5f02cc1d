"""Hypothesis strategies and noise models shared by the Wahba tests."""

from __future__ import annotations

import numpy as np
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation


@st.composite
def attitudes(draw: st.DrawFn) -> Rotation:
    """Uniform random attitudes, a third of them within 1e-3 rad of 180 degrees."""
    q = np.array(draw(st.lists(st.floats(-1, 1), min_size=4, max_size=4)))
    if np.linalg.norm(q) < 1e-3:
        q = np.array([0.3, -0.2, 0.5, 0.7])
    rotation = Rotation.from_quat(q)
    if draw(st.booleans()) and draw(st.booleans()):
        axis = rotation.as_rotvec()
        axis = axis / np.linalg.norm(axis) if np.linalg.norm(axis) > 1e-6 else np.array([1.0, 0, 0])
        rotation = Rotation.from_rotvec((np.pi - draw(st.floats(0.0, 1e-3))) * axis)
    return rotation


@st.composite
def wahba_problems(
    draw: st.DrawFn, min_vectors: int = 2, max_vectors: int = 50, sigma_decades: float = 3.0
):
    """Noise-free problems: (truth, body, reference, weights), well-spread directions.

    Sensor sigmas are log-uniform over ``sigma_decades`` decades below 0.1
    (weights ``1/sigma^2`` then span twice as many decades).
    """
    truth = draw(attitudes())
    n = draw(st.integers(min_vectors, max_vectors))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    while True:
        reference = rng.normal(size=(n, 3))
        reference /= np.linalg.norm(reference, axis=1, keepdims=True)
        gram = reference @ reference.T
        if np.sqrt(np.clip(1 - gram**2, 0, None)).max() > 0.2:
            break
    sigmas = 10.0 ** rng.uniform(-1 - sigma_decades, -1, size=n)
    return truth, truth.apply(reference), reference, 1.0 / sigmas**2


def noisy_body(
    truth: Rotation, reference: np.ndarray, sigmas: np.ndarray, rng: np.random.Generator
) -> np.ndarray:
    """Direction-cosine noise: ``b = normalise(A r + sigma * eps)``, eps ~ N(0, I3)."""
    b = truth.apply(reference) + sigmas[:, None] * rng.normal(size=reference.shape)
    return b / np.linalg.norm(b, axis=-1, keepdims=True)


def noisy_problem(
    n: int, sigma: float, seed: int, truth_seed: int
) -> tuple[Rotation, np.ndarray, np.ndarray, np.ndarray]:
    """(truth, body, reference, sigmas): ``n`` random unit directions with noise ``sigma``."""
    rng = np.random.default_rng(seed)
    truth = Rotation.random(random_state=truth_seed)
    reference = rng.normal(size=(n, 3))
    reference /= np.linalg.norm(reference, axis=1, keepdims=True)
    sigmas = np.full(n, sigma)
    return truth, noisy_body(truth, reference, sigmas, rng), reference, sigmas
