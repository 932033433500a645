"""The online step in one C call against the Python path it replaces: the same answers, bit for bit.

Where the C ports and the online extension (``_online_native.c``) build, a pilot
filter's ``update_plain`` and ``update_quiet`` read a plain sample dict, step the port
and build the plain dicts in C. They must answer what the Python path answers
(``_consume`` then ``_plain_of_row``, the path taken where the extension is absent):
compared as pickled bytes, so a float's sign, a NaN and the dicts' key order count.
A sample the C path does not take as it is (numpy or integer values, an infinite
value, an unknown key) goes the Python way: converted, or refused with its message,
and the filter not stepped. Also covered: a reset rebinds the step to the new records,
the four ways of feeding a filter can be mixed, the health dict is new each call and
refreshed when the pins change, and a filter holding the step is collected.
"""

import gc
import math
import pickle
import sysconfig
import weakref
from pathlib import Path

import numpy as np
import pytest

from manualcontrol.envs import _native
from manualcontrol.estimators import DEKF, RML, DualUKF, JointUKF, _online_native
from manualcontrol.pilots import Pilot, simulate

MEMBERS = (DEKF, RML, JointUKF, DualUKF)
SETTINGS = dict(model="precision", ce="DI", initial_variance="causal", initial={"K_p": 0.24})

built = _native.native_enabled() and _online_native.library() is not None
needs_extension = pytest.mark.skipif(
    not built, reason="the online extension is not built here: " + _online_native.failure()
)


@pytest.fixture(scope="module")
def samples():
    """A DI precision pilot's episode as the observer feeds it, with dropped samples."""
    recording = simulate(
        Pilot("precision", dict(K_p=0.24, K_v=0.36, omega_nms=8.0, zeta_nms=0.45, tau_v=0.3)),
        "DI",
        "popovici2017",
        seed=3,
        measurement_time=15.0,
    )
    table = [
        {"t": float(t), "e": float(e), "u": float(u)}
        for t, e, u in zip(recording.t, recording.e, recording.u, strict=True)
    ]
    for k in range(300, 330):  # the stick lost for 0.3 s
        table[k]["u"] = math.nan
    table[700]["e"] = math.nan
    del table[900]["t"]  # a sample without its time: t0 + k dt
    return table


def python_plain(estimator, sample):
    """The Python path's answer (what update_plain gives without the extension)."""
    return estimator._plain_of_row(estimator._consume(sample))


def fresh(member):
    estimator = member(**SETTINGS)
    estimator.reset(0.01, t0=0.0)
    return estimator


@needs_extension
@pytest.mark.parametrize("member", MEMBERS, ids=lambda m: m.__name__)
def test_the_c_answers_are_the_python_answers_bit_for_bit(member, samples):
    fast, slow = fresh(member), fresh(member)
    answers = [fast.update_plain(sample) for sample in samples]
    assert type(fast._online).__name__ == "OnlineStep"  # the C path ran
    expected = [python_plain(slow, sample) for sample in samples]
    assert pickle.dumps(answers) == pickle.dumps(expected)
    assert answers[900]["t"] == 900 * 0.01  # the reset's t0 + k dt
    # the pins changed along the run, so the health was read again from Python
    assert len({repr(answer["health"]) for answer in answers}) > 1


@needs_extension
@pytest.mark.parametrize("member", (DEKF, RML), ids=lambda m: m.__name__)
def test_quiet_updates_leave_the_python_estimate_in_the_row(member, samples):
    fast, slow = fresh(member), fresh(member)
    times = [fast.update_quiet(sample) for sample in samples[:500]]
    assert type(fast._online).__name__ == "OnlineStep"  # the C path ran
    expected = [slow._consume(sample) for sample in samples[:500]]
    assert times == expected
    for mine, theirs in zip(fast.latest(), slow.latest(), strict=True):
        assert mine.tobytes() == theirs.tobytes()
    assert pickle.dumps(fast.latest_plain(times[-1])) == pickle.dumps(
        slow.latest_plain(expected[-1])
    )


@needs_extension
def test_mixed_feeding_and_a_reset_give_the_python_numbers(samples):
    fast, slow = fresh(DEKF), fresh(DEKF)
    for k, sample in enumerate(samples[:400]):
        if k % 4 == 0:
            mine = fast.update_plain(sample)
        elif k % 4 == 1:
            mine = fast.update_quiet(sample) and fast.latest_plain(sample["t"])
        elif k % 4 == 2:
            mine = fast.update(sample)
            mine = {"t": mine.t, "mean": dict(mine.mean)}
        else:
            fast.update_block(np.array([[sample["e"], sample["u"]]]), t=sample["t"])
            mine = fast.latest_plain(sample["t"])
        theirs = python_plain(slow, sample)
        assert pickle.dumps(mine) == pickle.dumps({key: theirs[key] for key in mine})
    bound = fast._online
    fast.reset(0.01, t0=2.0)  # new records: the step binds again
    slow.reset(0.01, t0=2.0)
    later = [fast.update_plain(sample) for sample in samples[400:700]]
    assert fast._online is not bound
    assert pickle.dumps(later) == pickle.dumps([python_plain(slow, s) for s in samples[400:700]])


@needs_extension
def test_samples_the_c_path_does_not_take_go_the_python_way(samples):
    fast, slow = fresh(DEKF), fresh(DEKF)
    converted = [
        {"t": 0.0, "e": np.float64(samples[0]["e"]), "u": samples[0]["u"]},  # numpy float
        {"t": 0.01, "e": samples[1]["e"], "u": 0},  # an integer stick
        {"t": np.float64(0.02), "e": samples[2]["e"], "u": samples[2]["u"]},  # numpy time
        {"e": samples[3]["e"], "u": samples[3]["u"]},  # no time: t0 + k dt in C
    ]
    answers = [fast.update_plain(sample) for sample in converted]
    expected = [python_plain(slow, sample) for sample in converted]
    assert pickle.dumps(answers) == pickle.dumps(expected)
    assert answers[3]["t"] == 0.03
    before = fast.latest()[0].tobytes()
    with pytest.raises(ValueError, match=r"sample\['u'\] must be finite or NaN"):
        fast.update_plain({"t": 0.04, "e": 0.1, "u": math.inf})
    with pytest.raises(TypeError, match=r"unknown key.*speed"):
        fast.update_quiet({"t": 0.04, "e": 0.1, "u": 0.2, "speed": 1.0})
    with pytest.raises(TypeError, match="sample must be a mapping"):
        fast.update_plain([0.1, 0.2])
    assert fast.latest()[0].tobytes() == before  # refused samples step nothing
    assert fast._k == 4


@needs_extension
def test_each_answer_is_new_and_the_filter_goes_with_its_last_reference(samples):
    estimator = fresh(DEKF)
    first = estimator.update_plain(samples[0])
    first["health"]["pinned"].append("K_p")
    first["mean"]["K_p"] = -1.0
    second = estimator.update_plain(samples[1])
    assert "K_p" not in second["health"]["pinned"]
    assert second["mean"]["K_p"] != -1.0
    # the step calls back into the filter for its health: no cycle, so no collector needed
    alive = weakref.ref(estimator)
    gc.disable()
    try:
        del estimator, first, second
        assert alive() is None
    finally:
        gc.enable()


class LabelledDEKF(DEKF):
    """A member whose answer adds a key: the C step must not answer for it."""

    def _plain_of_row(self, t):
        return {**super()._plain_of_row(t), "member": "labelled"}


class Key(str):
    """A str subclass: its hash may run Python code, here emptying the sample it keys."""

    sample = None

    def __hash__(self):
        if Key.sample is not None:
            emptied, Key.sample = Key.sample, None
            emptied.clear()
        return str.__hash__(self)


@needs_extension
def test_a_subclass_that_changes_the_answer_and_str_subclass_keys_go_the_python_way(samples):
    labelled = LabelledDEKF(**SETTINGS)
    labelled.reset(0.01, t0=0.0)
    assert labelled.update_plain(samples[0])["member"] == "labelled"
    assert labelled._online is False
    fast, slow = fresh(DEKF), fresh(DEKF)
    odd = {Key("t"): samples[0]["t"], Key("e"): samples[0]["e"], "u": samples[0]["u"]}
    assert pickle.dumps(fast.update_plain(odd)) == pickle.dumps(python_plain(slow, odd))
    assert type(fast._online).__name__ == "OnlineStep"  # bound, but this sample went around
    # a key that changes its dict while it is read: Python's own error, nothing freed early
    changing = {Key("e"): 0.1, "u": 0.2}
    Key.sample = changing
    with pytest.raises(RuntimeError, match="changed size"):
        fast.update_plain(changing)
    assert fast._k == 1


@needs_extension
def test_the_step_refuses_arguments_that_do_not_fit():
    lib = _online_native.library()
    good = dict(
        step=1, records=1, inputs=1, n_inputs=0, keys=("e", "u"), allowed=frozenset({"e", "u"}),
        u_at=1, e_at=0, mean=1, std=1, scalar=1, flag=1, pinned=1, n_flag=4,
        columns=("K_p",), health_of=dict, t0=0.0, dt=0.01, keep=(),
    )  # fmt: skip
    lib.OnlineStep(**good)
    with pytest.raises(ValueError, match="u at 2"):
        lib.OnlineStep(**{**good, "u_at": 2})
    with pytest.raises(ValueError, match="3 flags"):
        lib.OnlineStep(**{**good, "n_flag": 3})
    with pytest.raises(ValueError, match="every address"):
        lib.OnlineStep(**{**good, "step": 0})
    with pytest.raises(TypeError, match="health_of must be callable"):
        lib.OnlineStep(**{**good, "health_of": 1})


def test_where_the_extension_is_not_built_the_python_path_answers(samples, monkeypatch):
    monkeypatch.setattr(_online_native, "library", lambda: None)
    estimator, slow = fresh(DEKF), fresh(DEKF)
    answers = [estimator.update_plain(sample) for sample in samples[:200]]
    assert estimator._online is False
    assert pickle.dumps(answers) == pickle.dumps([python_plain(slow, s) for s in samples[:200]])


@pytest.mark.skipif(
    _native._compiler() is None
    or not (Path(sysconfig.get_paths()["include"]) / "Python.h").is_file(),
    reason="no C compiler or no Python headers here",
)
def test_an_extension_without_pythons_headers_is_not_built_and_says_why(tmp_path, monkeypatch):
    monkeypatch.delenv("MANUALCONTROL_NATIVE", raising=False)
    source = tmp_path / "_probe.c"
    source.write_text(
        "#include <Python.h>\n"
        'static struct PyModuleDef probe = {PyModuleDef_HEAD_INIT, "_probe", NULL, -1, NULL};\n'
        "PyMODINIT_FUNC PyInit__probe(void) { return PyModule_Create(&probe); }\n"
    )
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "cache"))
    module = _native.native_extension(source, "_probe")
    assert module is not None and module.__name__ == "_probe"
    other = tmp_path / "_probe2.c"
    other.write_text(source.read_text().replace("_probe", "_probe2"))
    monkeypatch.setattr(
        _native.sysconfig, "get_paths", lambda: {"include": str(tmp_path / "no-headers")}
    )
    assert _native.native_extension(other, "_probe2") is None
    assert "Python.h" in _native.native_failure(other, extension="_probe2")
    assert _native.native_failure(other) == ""  # the C library of that source: not tried
