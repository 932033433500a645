"""What every test process shares."""

import os
import sys

import pytest

if "PYTEST_XDIST_WORKER" in os.environ:
    # `pytest -n auto` run by hand, as make test does (the Makefile sets these for it):
    # one worker a core, and a worker whose torch, OpenMP and BLAS thread pools each
    # took every core spun them against the other workers (measured side by side on 2
    # cores: the full suite 249 s so, 168 s with one thread a worker). The variables
    # are read when those libraries load, which is after this file; a value the user
    # set is kept, and BLAS loaded already (by a plugin) is limited here
    for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(name, "1")
    if "numpy" in sys.modules and os.environ["OPENBLAS_NUM_THREADS"] == "1":
        from threadpoolctl import threadpool_limits

        threadpool_limits(1, user_api="blas")


@pytest.fixture
def shared_harmonic_forcing():
    """vanderel-bw4 with its disturbance moved onto the target's harmonics.

    Each harmonic then carries a line of both forcings, as no built-in preset has it:
    the describing function, its remnant and the error's reading must count it once.
    """
    # imported here: the variables above must be set before numpy and torch load
    from manualcontrol.envs.signals import ForcingPair, Multisine, forcing_preset

    forcing = forcing_preset("vanderel-bw4")
    target = forcing.target
    shared = Multisine(
        target.frequencies,
        forcing.disturbance.amplitudes,
        forcing.disturbance.phases,
        target.measurement_time,
    )
    return ForcingPair(target, shared)
