"""Many filters of one kind as one set of records: stacked arrays, one compiled call.

A member's compiled step reads its state from small records (namedtuples of arrays,
possibly nested). ``n`` filters of the same member with the same settings have records
of the same shapes, so they can live in one set of records whose every array has a
leading axis of length ``n`` (:func:`stack_records`). A compiled loop then steps all of
them in one call: :func:`take` gives filter ``i``'s records as views of row ``i`` of
every stacked array, of exactly the types of one filter's own records, so the member's
one-sample step (already compiled for those types) runs on them unchanged and gives
the numbers it gives one filter, bit for bit.

Arrays shared between a filter's records (the DEKF's parameter vector is both its
belief's and its report's) stay shared in the stack: each distinct array is stacked
once and every field that held it holds the stacked one. Fields that are not arrays
(flags fixed at build) are kept as they are, and must be equal across the stack.

Why views are taken inside the loop and not built once in Python: a typed list of
``n`` records costs a reference count on every access (measured 7.4 us per filter-step
against the step's 2-4 us). Views taken in a compiled loop with numba's reference
counting on cost two atomic counts per array, about 2 us per filter-step for the DEKF's
sixty arrays, as much as its arithmetic. So the batched loops are compiled with it off,
as the steps are: the stack outlives every call, and :func:`take` returns records (never
a bare array, which numba refuses to return without reference counting).

Why compiled :func:`take` is a typing rule and a lowering, not an ``@overload``: an
overload is a Python function numba compiles for every record type it meets (its
nested records too) before the loop that calls it, and those compilations were a third
of each batched kernel's first compile. The lowering writes the same views, numba's
own ``a[i]`` of each array, straight into the calling loop, and compiles nothing of
its own.
"""

from __future__ import annotations

import operator
from typing import Any

import numba  # noqa: F401  (a kernel module: its lowering compiles into callers)
import numpy as np
from numba.core import types
from numba.extending import lower_builtin, type_callable

__all__ = [
    "loop_samples",
    "one_filter_loop",
    "put_record",
    "stack_of_one",
    "stack_records",
    "take",
]


def _is_record(value: Any) -> bool:
    return isinstance(value, tuple) and hasattr(value, "_fields")


def loop_samples(values: Any) -> np.ndarray:
    """``values`` as the batched loops take samples: C-contiguous float64, writable.

    numba types a read-only array apart from a writable one and compiles a kernel once
    per type: a recording's signals are read-only, a batch's and a block's are not, so
    without this the loop, with the filter's step optimised into it, would be compiled
    twice for the same numbers. A read-only array is copied (one pass over the samples,
    against a filter step per sample).
    """
    array = np.ascontiguousarray(values, dtype=np.float64)
    return array if array.flags.writeable else array.copy()


def one_filter_loop(
    stacked: tuple[Any, Any], inputs: Any, u: Any, e: Any, out_rows: np.ndarray
) -> tuple:
    """The batched loop's arguments that run one filter through samples in order.

    ``stacked`` is :func:`stack_of_one` of the filter's ``(records, out)``; sample
    ``k`` (``inputs[k], u[k], e[k]``) steps it and writes its estimate into row
    ``out_rows[k]`` of ``out``: ``arange`` for a whole run, zeros for the online block.
    """
    records, out = stacked
    n = len(u)
    every = np.ones(n, dtype=np.bool_)
    first = np.zeros(n, dtype=np.int64)  # the one filter of the stack
    samples = (loop_samples(inputs), loop_samples(u), loop_samples(e))
    rows = np.ascontiguousarray(out_rows, dtype=np.int64)
    return (*records, *samples, every, first, rows, out)


def stack_records(record: Any, n: int) -> Any:
    """``n`` copies of ``record`` (a namedtuple of arrays, nested), stacked on a new first axis.

    Every array ``a`` becomes a C-contiguous ``(n, *a.shape)`` array whose rows are
    copies of ``a``; an array appearing in several fields is stacked once and shared
    again (see the module docstring); other fields are kept.
    """
    memo: dict[int, np.ndarray] = {}

    def stacked(value: Any) -> Any:
        if _is_record(value):
            return type(value)(*(stacked(field) for field in value))
        if isinstance(value, tuple):
            return tuple(stacked(field) for field in value)
        if isinstance(value, np.ndarray):
            key = id(value)
            if key not in memo:
                memo[key] = np.repeat(value[np.newaxis], n, axis=0)  # a writable copy
            return memo[key]
        return value

    return stacked(record)


def stack_of_one(record: Any) -> Any:
    """One filter's ``record`` as a stack of one: views ``a[np.newaxis]`` of its own arrays.

    Of the types :func:`stack_records` gives (C-contiguous, one more axis), so the
    batched loops step it; stepping the stack steps the filter itself, in place. A
    batched loop fed a block of samples with every row index 0 runs the one filter
    through them in order, in one compiled call.
    """
    if _is_record(record):
        return type(record)(*(stack_of_one(field) for field in record))
    if isinstance(record, tuple):
        return tuple(stack_of_one(field) for field in record)
    if isinstance(record, np.ndarray):
        if not record.flags.c_contiguous:
            raise ValueError("stack_of_one needs C-contiguous arrays, as the filters keep them")
        return record[np.newaxis]
    return record


def put_record(stack: Any, record: Any, i: int) -> None:
    """Copy one filter's ``record`` into row ``i`` of every array of ``stack``."""
    if _is_record(stack) or isinstance(stack, tuple):
        for into, value in zip(stack, record, strict=True):
            put_record(into, value, i)
    elif isinstance(stack, np.ndarray):
        stack[i] = record


def take(record: Any, i: int) -> Any:
    """Filter ``i``'s records in a stack: views of row ``i`` of every array.

    Callable from Python (on records and arrays) and from compiled code (on records:
    typed and lowered below); other fields are returned as they are.
    """
    if _is_record(record):
        return type(record)(*(take(field, i) for field in record))
    if isinstance(record, tuple):
        return tuple(take(field, i) for field in record)
    if isinstance(record, np.ndarray):
        return record[i]
    return record


def _row_type(typing_context: Any, record: types.BaseTuple) -> types.BaseTuple:
    """The numba type of :func:`take` on a record of type ``record``."""
    kinds = []
    for kind in record.types:
        if isinstance(kind, types.Array):  # numba's own type of ``a[i]``
            row = typing_context.resolve_function_type(operator.getitem, (kind, types.intp), {})
            kinds.append(row.return_type)
        elif isinstance(kind, types.BaseTuple):
            kinds.append(_row_type(typing_context, kind))
        else:
            kinds.append(kind)
    if isinstance(record, types.BaseNamedTuple):
        return types.BaseTuple.from_types(kinds, record.instance_class)
    return types.BaseTuple.from_types(kinds)


@type_callable(take)
def _type_take(typing_context: Any) -> Any:
    def typer(record: Any, i: Any) -> Any:
        if isinstance(record, types.BaseTuple) and isinstance(i, types.Integer):
            return _row_type(typing_context, record)
        return None

    return typer


def _row_views(
    context: Any,
    builder: Any,
    record: types.BaseTuple,
    rows: types.BaseTuple,
    value: Any,
    i: Any,
) -> Any:
    """The tuple of row ``i``'s views, built in the calling loop.

    Of type ``rows`` (:func:`_row_type`, the typing rule's answer). Each array field
    is indexed by numba's own ``a[i]``, a nested record taken, anything else passed on.
    """
    fields = []
    for j, (kind, row) in enumerate(zip(record.types, rows.types, strict=True)):
        field = builder.extract_value(value, j)
        if isinstance(kind, types.Array):
            getitem = context.get_function(operator.getitem, row(kind, types.intp))
            fields.append(getitem(builder, (field, i)))
        elif isinstance(kind, types.BaseTuple):
            fields.append(_row_views(context, builder, kind, row, field, i))
        else:
            if context.enable_nrt:  # a new reference, as a[i] gives
                context.nrt.incref(builder, kind, field)
            fields.append(field)
    return context.make_tuple(builder, rows, fields)


@lower_builtin(take, types.BaseTuple, types.Integer)
def _lower_take(context: Any, builder: Any, signature: Any, arguments: Any) -> Any:
    record, index = arguments
    i = context.cast(builder, index, signature.args[1], types.intp)
    return _row_views(context, builder, signature.args[0], signature.return_type, record, i)
