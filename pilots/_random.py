"""The random generator every simulation of the package draws its noise from."""

from __future__ import annotations

from typing import Any

import numpy as np

from manualcontrol.envs._validation import check_int

__all__ = ["as_generator"]


def as_generator(seed: int | np.random.Generator | None) -> tuple[np.random.Generator, Any]:
    """The generator of ``seed`` and what a recording stores to repeat the run.

    An int seeds a new generator (stored as the int); a generator is used as it is
    (stored as ``"generator"``); None draws a fresh seed, stored like an int. The
    simulations, the open-loop system and the controllers acting in the environments
    all start from it, so the same seed gives the same noise in each.
    """
    if isinstance(seed, np.random.Generator):
        return seed, "generator"
    if seed is None:
        seed = int(np.random.SeedSequence().generate_state(1)[0])
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
        raise TypeError(f"seed must be an int, a numpy Generator or None, got {seed!r}")
    seed = check_int("seed", seed, minimum=0)
    return np.random.default_rng(seed), seed
