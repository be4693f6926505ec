"""Shared demonstration sets for canal_core tests (all generated in code or shipped by a wheel)."""

from __future__ import annotations

import numpy as np
import pytest
from core_data import helix_demos, sleeve_demos, tube_demos

__all__ = ["helix_demos", "sleeve_demos", "tube_demos"]


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(1234)
