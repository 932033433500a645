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
"""

from __future__ import annotations

from typing import Any

import numba  # noqa: F401  (a kernel module: its overload compiles into callers)
import numpy as np
from numba.core import types
from numba.extending import overload

__all__ = ["put_record", "stack_of_one", "stack_records", "take"]


def _is_record(value: Any) -> bool:
    return isinstance(value, tuple) and hasattr(value, "_fields")


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

    Callable from Python (on records and arrays) and from compiled code (the overload
    below, on records); other fields are returned as they are.
    """
    if _is_record(record):
        return type(record)(*(take(field, i) for field in record))
    if isinstance(record, tuple):
        return tuple(take(field, i) for field in record)
    if isinstance(record, np.ndarray):
        return record[i]
    return record


@overload(take, inline="always")
def _take_compiled(record, i):  # unannotated: numba matches it to the impls' signatures
    if not isinstance(record, types.BaseTuple):
        return None
    # one constructor call over the fields, generated per record type: an array field
    # is indexed here, a nested record taken, anything else passed on. The impl returns
    # a tuple and never a bare array, which numba allows with reference counting off.
    fields = []
    for j, kind in enumerate(record.types):
        if isinstance(kind, types.Array):
            fields.append(f"record[{j}][i]")
        elif isinstance(kind, types.BaseTuple):
            fields.append(f"take(record[{j}], i)")
        else:
            fields.append(f"record[{j}]")
    namespace = {"take": take}
    if isinstance(record, types.BaseNamedTuple):
        namespace["record_type"] = record.instance_class
        body = f"record_type({', '.join(fields)})"
    else:
        body = f"({''.join(field + ', ' for field in fields)})"
    exec(f"def impl(record, i):\n    return {body}\n", namespace)
    return namespace["impl"]
