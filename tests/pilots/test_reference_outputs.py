"""Simulation outputs equal those of the code at commit dd5f117, before its speed work.

The speed work replaced scipy's per-matrix exponential by a compiled one, grouped parameter
sets by runs instead of sorting for unique rows, and asked the discretisation for the
ramp term of the delayed inputs only. Each changes results at rounding level; the
stated tolerance is 1e-12 relative (largest difference over the largest value of the
signal). Measured 3e-15 .. 3e-14, the largest on the badly scaled Padé-5 loop.
``make_reference_outputs.py`` wrote the stored numbers (see its docstring).
"""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from make_reference_outputs import cases, varying_traces

STORED = Path(__file__).parent / "data" / "reference_outputs_dd5f117.npz"


@pytest.fixture(scope="module")
def today():
    return cases()


@pytest.mark.parametrize("name", sorted(np.load(STORED).files))
def test_equal_to_the_stored_reference_numbers(today, name):
    before = np.load(STORED)[name]
    assert today[name].shape == before.shape
    difference = np.max(np.abs(today[name] - before)) / np.max(np.abs(before))
    assert difference < 1e-12, f"{name}: {difference:.2e}"


def test_several_perception_sets_share_one_discretisation_bit_for_bit():
    from manualcontrol.pilots.simulation import isolated_pilot_output, isolated_pilot_outputs

    rng = np.random.default_rng(2)
    n = 1500
    ramp = np.linspace(0.0, 1.0, n)
    traces = {
        **varying_traces(n),
        "K_f": 0.9 + 0.1 * ramp,
        "omega_f": 1.0 + 0.2 * ramp,
        "tau_f": 0.6 - 0.3 * ramp,
    }
    sets = [{"ft_far": rng.standard_normal(n), "y": rng.standard_normal(n)} for _ in range(3)]
    together = isolated_pilot_outputs("preview", traces, sets, 0.01)
    for shared, perceptions in zip(together, sets, strict=True):
        alone = isolated_pilot_output("preview", traces, perceptions, 0.01)
        np.testing.assert_array_equal(shared, alone)
    with pytest.raises(ValueError, match="at least one set"):
        isolated_pilot_outputs("preview", traces, [], 0.01)
    short = {"ft_far": sets[0]["ft_far"][:-1], "y": sets[0]["y"][:-1]}
    with pytest.raises(ValueError, match="the same samples, got lengths"):
        isolated_pilot_outputs("preview", traces, [sets[0], short], 0.01)
    with pytest.raises(ValueError, match="perceptions must include y"):
        isolated_pilot_outputs("preview", traces, [sets[0], {"ft_far": sets[0]["ft_far"]}], 0.01)
