"""The RTS smoother's C port against its numba kernel, byte for byte.

The numba kernel (``filters/_smoother_kernels.rts_smooth``) is the reference the port
must equal exactly (``filters/_smoother_native.c``): on runs of every link kind, on
priors that factor, that factor only once loaded and that never do, and through
``smooth`` on every smoothable member's own result.
"""

import numpy as np
import pytest

from manualcontrol.envs import _native
from manualcontrol.estimators import ESTIMATORS
from manualcontrol.estimators.filters import _smoother_native
from manualcontrol.estimators.filters._smoother_kernels import rts_smooth as numba_rts
from manualcontrol.estimators.filters.smoothers import (
    LINK_CROSS,
    LINK_RANDOM_WALK,
    LINK_TRANSITION,
    smoother_work,
)
from manualcontrol.pilots import Pilot, simulate

pytestmark = pytest.mark.skipif(
    _native._compiler() is None or _smoother_native.library() is None,
    reason="no C compiler here: the smoother's C port cannot be built",
)


def _spd(rng, n, scale=1.0):
    a = rng.normal(size=(n, n))
    return scale * (a @ a.T + 0.1 * np.eye(n))


def _run(seed, N=60, n=4, broken=()):
    """A stored run: filtered and predicted beliefs, links; ``broken`` priors not PD."""
    rng = np.random.default_rng(seed)
    x_f, x_p = rng.normal(size=(N, n)), rng.normal(size=(N, n))
    P_f = np.array([_spd(rng, n, 0.5) for _ in range(N)]).reshape(N, n, n)
    P_p = np.array([_spd(rng, n) for _ in range(N)]).reshape(N, n, n)
    for k, how in broken:
        if how == "semidefinite":  # factors only once loaded
            v = rng.normal(size=n)
            P_p[k] = np.outer(v, v)
        else:  # never factors: not finite
            P_p[k, 0, 0] = np.nan
    link = rng.normal(size=(N, n, n))
    return x_f, P_f, x_p, P_p, link


def _both(run, kind):
    x_f, P_f, x_p, P_p, link = run
    N, n = x_f.shape
    outputs = []
    for method in ("c", "numba"):
        x_s, P_s = np.zeros((N, n)), np.zeros((N, n, n))
        arguments = (x_f, P_f, x_p, P_p, link, kind, x_s, P_s, smoother_work(n))
        if method == "c":
            status = _smoother_native.rts_smooth(_smoother_native.library(), *arguments)
        else:
            status = numba_rts(*arguments)
        outputs.append((status, x_s, P_s))
    return outputs


@pytest.mark.parametrize("kind", [LINK_CROSS, LINK_TRANSITION, LINK_RANDOM_WALK])
@pytest.mark.parametrize(
    "broken",
    [(), ((30, "semidefinite"), (5, "semidefinite")), ((20, "nan"), (40, "semidefinite"))],
    ids=["factors", "loaded", "unfactorable"],
)
def test_the_c_pass_is_the_numba_pass_bit_for_bit(kind, broken):
    (c_status, c_x, c_P), (n_status, n_x, n_P) = _both(_run(7, broken=broken), kind)
    assert c_status == n_status
    assert c_x.tobytes() == n_x.tobytes() and c_P.tobytes() == n_P.tobytes()
    # the cases reach the branches they name
    if not broken:
        assert c_status == 0
    elif broken[0][1] == "nan":
        assert c_status == -1  # one sample kept its filtered belief
    else:
        assert c_status == 2  # two priors factored once loaded


def test_an_empty_run_and_a_single_sample_are_what_numba_makes_of_them():
    for N in (0, 1):
        (c_status, c_x, c_P), (n_status, n_x, n_P) = _both(_run(3, N=N), LINK_CROSS)
        assert c_status == n_status == 0
        assert c_x.tobytes() == n_x.tobytes() and c_P.tobytes() == n_P.tobytes()


def test_a_wrong_array_is_refused_by_name():
    x_f, P_f, x_p, P_p, link = _run(1)
    N, n = x_f.shape
    lib = _smoother_native.library()
    arguments = [x_f, P_f, x_p, P_p, link, LINK_CROSS, np.zeros((N, n)), np.zeros((N, n, n))]
    with pytest.raises(ValueError, match=r"P_smooth must be C-contiguous float64 of shape"):
        _smoother_native.rts_smooth(lib, *arguments[:7], np.zeros((N, n, n + 1)), smoother_work(n))
    with pytest.raises(ValueError, match=r"link must be C-contiguous float64"):
        arguments[4] = link[:, :, ::-1]
        _smoother_native.rts_smooth(lib, *arguments, smoother_work(n))


#: Every smoothed twin that tracks a compensatory recording (the Zhao filters' come from
#: the driving task; their pass is the same function, tested on its own above).
TWINS = sorted(
    name for name in ESTIMATORS if name.endswith("-smoothed") and not name.startswith("zhao")
)


@pytest.mark.parametrize("name", TWINS)
def test_every_smoothed_twin_smooths_to_the_same_bytes_in_c_and_numba(name, monkeypatch):
    from manualcontrol.estimators.offline import smoothing

    pilot = Pilot.typical("schiess-roland" if "schiess" in name else "precision", "DI")
    recording = simulate(pilot, "DI", measurement_time=15.0, run_in=0.0, seed=0)
    base = ESTIMATORS[name.removesuffix("-smoothed")].build({})
    result = base.estimate(recording, smoother_inputs=True)
    c = smoothing.smooth(result)
    monkeypatch.setattr(smoothing, "_smoother_pass", lambda: numba_rts)
    reference = smoothing.smooth(result)
    assert not np.array_equal(c.mean, result.mean)  # the pass smoothed something
    for field in ("mean", "std", "states"):
        assert (
            np.asarray(getattr(c, field)).tobytes()
            == np.asarray(getattr(reference, field)).tobytes()
        ), field
