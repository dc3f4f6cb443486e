"""Shared fixtures: seeded generators, uniform samples of a system's domain."""

from __future__ import annotations

import numpy as np
import pytest
import torch

torch.set_num_threads(1)


def sample_domain(system, n: int, seed: int = 0) -> np.ndarray:
    """n uniform states of the system's training box, (n, system.n)."""
    lo, hi = system.domain
    return lo + (hi - lo) * np.random.default_rng(seed).random((n, system.n))


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
