"""Shared pytest fixtures."""

from __future__ import annotations

import numpy as np
import pytest

SEED = 20240611


@pytest.fixture
def rng() -> np.random.Generator:
    """A seeded generator, fresh for every test (never the global numpy state)."""
    return np.random.default_rng(SEED)
