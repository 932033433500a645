"""Simulation outputs equal those of the code before issue 16 (commit dd5f117).

Issue 16 replaced scipy's per-matrix exponential by a compiled one, grouped parameter
sets by runs instead of sorting for unique rows, and asked the discretisation for the
ramp term of the delayed inputs only. Each changes results at rounding level; the
stated tolerance is 1e-12 relative (largest difference over the largest value of the
signal). Measured 3e-15 .. 3e-14, the largest on the badly scaled Padé-5 loop.
``make_issue16_reference.py`` wrote the stored numbers (see its docstring).
"""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from make_issue16_reference import cases

STORED = Path(__file__).parent / "data" / "before_issue16.npz"


@pytest.fixture(scope="module")
def today():
    return cases()


@pytest.mark.parametrize("name", sorted(np.load(STORED).files))
def test_equal_to_the_numbers_before_issue16(today, name):
    before = np.load(STORED)[name]
    assert today[name].shape == before.shape
    difference = np.max(np.abs(today[name] - before)) / np.max(np.abs(before))
    assert difference < 1e-12, f"{name}: {difference:.2e}"
