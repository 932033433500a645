"""One filter's records out of a stack, in Python and in compiled code: the same views.

The batched loops step filter ``i`` on ``take(stack, i)``: views of row ``i`` of every
stacked array. A view that is a copy, another row, or a field in the wrong place would
step the wrong state, so the compiled ``take`` is checked against the Python one on a
nested record of every field kind the members' records hold, and through writes. The
members' own callers of their batched loop (a run, an online block, a batch) are checked
to dispatch it on one tuple of types, so numba compiles it once.
"""

from collections import defaultdict, namedtuple
from types import SimpleNamespace

import numba
import numpy as np
import pytest

from manualcontrol.estimators.filters.batch import stack_records, take

Inner = namedtuple("Inner", "cube pair")
Outer = namedtuple("Outer", "matrix counts flag inner shared again")


def a_stack(n=3):
    shared = np.zeros(2)
    record = Outer(
        matrix=np.zeros((2, 3)),
        counts=np.zeros(4, dtype=np.int64),
        flag=7,
        inner=Inner(cube=np.zeros((2, 2, 2)), pair=(np.zeros(3), 0.5)),
        shared=shared,
        again=shared,  # one array in two fields, as the DEKF's parameter vector is
    )
    stack = stack_records(record, n)
    rng = np.random.default_rng(3)
    for array in (stack.matrix, stack.inner.cube, stack.inner.pair[0], stack.shared):
        array[...] = rng.normal(size=array.shape)
    stack.counts[...] = rng.integers(0, 100, size=stack.counts.shape)
    return stack


@numba.njit(_nrt=False)
def _sums(stack, i):
    views = take(stack, i)
    return (
        views.matrix.sum(),
        views.counts.sum(),
        views.flag,
        views.inner.cube.sum(),
        views.inner.pair[0].sum() + views.inner.pair[1],
        views.again.sum(),
    )


@numba.njit(_nrt=False)
def _write(stack, i, value):
    views = take(stack, i)
    views.matrix[1, 2] = value
    views.inner.cube[1, 0, 1] = value
    views.inner.pair[0][2] = value
    views.again[0] = value  # and so the shared field, which is the same array


@numba.njit
def _views(stack, i):  # with reference counting on: the views outlive the call
    return take(stack, i)


@pytest.mark.parametrize("i", [0, 2, np.int32(1)])
def test_the_compiled_take_reads_the_rows_python_take_reads(i):
    stack = a_stack()
    row = take(stack, int(i))
    expected = (
        row.matrix.sum(),
        row.counts.sum(),
        7,
        row.inner.cube.sum(),
        row.inner.pair[0].sum() + 0.5,
        row.shared.sum(),
    )
    assert _sums(stack, i) == expected


def test_writes_through_the_compiled_views_land_in_that_row_alone():
    stack = a_stack()
    written = (stack.matrix, stack.inner.cube, stack.inner.pair[0])
    before = [a.copy() for a in written]
    _write(stack, 1, 42.0)
    assert stack.matrix[1, 1, 2] == stack.inner.cube[1, 1, 0, 1] == 42.0
    assert stack.inner.pair[0][1, 2] == stack.shared[1, 0] == 42.0
    for after, old in zip(written, before, strict=True):
        changed = np.argwhere(after != old)
        assert set(changed[:, 0]) == {1}  # no other filter's state moved


def test_views_returned_to_python_are_counted_references_of_the_stack():
    stack = a_stack()
    views = [_views(stack, 2) for _ in range(200)]
    del stack  # the views alone keep the stacked arrays alive
    for view in views:
        assert isinstance(view, Outer) and isinstance(view.inner, Inner)
        assert view.matrix.shape == (2, 3) and view.inner.cube.shape == (2, 2, 2)
        assert view.counts.dtype == np.int64 and view.flag == 7
        assert view.inner.pair[1] == 0.5
        np.testing.assert_array_equal(view.matrix, views[0].matrix)
    views[0].matrix[0, 0] = 5.0
    assert views[-1].matrix[0, 0] == 5.0  # views of one row, not copies


class _TypesSeen:
    """A member's batched kernel that notes the types numba dispatches each call on."""

    def __init__(self, kernel):
        self.kernel, self.seen = kernel, []

    def __call__(self, *arguments):
        self.seen.append(tuple(self.kernel.typeof_pyval(a) for a in arguments))
        self.kernel(*arguments)

    def typeof_pyval(self, argument):
        return self.kernel.typeof_pyval(argument)

    @property
    def overloads(self):  # what shell.compiled_entry reads the entry point from
        return defaultdict(lambda: SimpleNamespace(entry_point=self))


@pytest.mark.parametrize("member", ["dekf", "rml", "joint-ukf", "dual-ukf"])
def test_a_run_an_online_block_and_a_batch_dispatch_alike_so_numba_compiles_one_loop(
    member, monkeypatch
):
    # numba compiles a kernel once per tuple of argument types. The batched loop serves
    # three callers: a whole run in estimate (the filter's records and its n-row output
    # as a stack of one, on a recording's read-only signals), update_block (the same
    # records and the one-row output) and a FilterBatch (copies stacked): were any of
    # their arguments to type differently, numba would compile the loop, and the step
    # optimised into it, once more (a read-only u did: 6 CPU-s for the DEKF)
    from manualcontrol.estimators.batch import FilterBatch
    from manualcontrol.estimators.registry import ESTIMATORS
    from manualcontrol.pilots import Pilot, simulate

    monkeypatch.setenv("MANUALCONTROL_NATIVE", "0")  # numba's path, where the types matter
    recording = simulate(
        Pilot("precision"), "popovici2017", "popovici2017", measurement_time=2.0, seed=0
    )
    assert not recording.u.flags.writeable  # a recording's signals are read-only
    estimator = ESTIMATORS[member].build({"initial_variance": "causal", "initial": {"K_p": 1.0}})
    seen = _TypesSeen(type(estimator)._step_many_kernel)
    monkeypatch.setattr(type(estimator), "_step_many_kernel", seen)
    estimator.estimate(recording, smooth=True)
    signals = estimator.signals(recording)
    keys = estimator.sample_keys
    estimator.reset(recording.dt)
    estimator.update_block(np.column_stack([signals[key][:5] for key in keys]))
    batch = FilterBatch(estimator, 3)
    batch.reset(recording.dt)
    batch.step({key: np.full(3, signals[key][0]) for key in keys})
    assert len(seen.seen) == 3  # the run, the block and the batch all went through it
    assert len(set(seen.seen)) == 1
