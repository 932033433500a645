"""One online sample of a pilot filter's C port in one call: the observer's fast path.

Online, at 100 Hz, a pilot filter's C port steps a sample in about a microsecond, and
the Python around it (entering the port through ctypes, reading the sample dict,
building the plain dicts an :class:`~manualcontrol.estimators.observer.
EstimatorObserver` reports) cost several times that. ``_online_native.c`` is a CPython
extension (the module ``_online_step``, built by :func:`~manualcontrol.envs._native.
native_extension` where a C compiler and Python's headers are at hand) whose
``OnlineStep`` does all three in C: :meth:`~manualcontrol.estimators.members.
pilot_filter.PilotFilter.update_plain` and ``update_quiet`` hand it each sample and
take its answer, or, where it answers None (a sample that is not a plain dict of
floats, an infinite value), take their Python path, which converts or raises as it
always has. The same port function steps on the same values, so the estimates are
bit for bit the Python path's (``tests/estimators/test_online_native.py``).
"""

from __future__ import annotations

import ctypes
from pathlib import Path
from typing import Any

from manualcontrol.envs._native import native_extension, native_failure

__all__ = ["ABI", "MODULE", "SOURCE", "failure", "function_address", "library"]

SOURCE = Path(__file__).with_name("_online_native.c")
#: The extension module's name (``PyInit__online_step`` in the source).
MODULE = "_online_step"
#: The layout version ``online_abi()`` reports: ``OnlineStep``'s arguments as bound here.
ABI = 1


def library() -> Any:
    """The built ``_online_step`` module, its layout checked, or None (the Python path runs).

    Raises ``RuntimeError`` where the built module's layout differs from this binding's
    (a C edit without the Python one).
    """
    module = native_extension(SOURCE, MODULE)
    if module is not None and module.online_abi() != ABI:
        raise RuntimeError(
            f"{SOURCE.name}'s layout {module.online_abi()} differs from its binding's {ABI}: "
            "edit the two together"
        )
    return module


def failure() -> str:
    """Why :func:`library` gave None in this process ('' if it did not)."""
    return native_failure(SOURCE, extension=MODULE)


def function_address(lib: ctypes.CDLL, name: str) -> int:
    """The address of the C port's exported function ``name`` (what ``OnlineStep`` calls)."""
    return ctypes.cast(getattr(lib, name), ctypes.c_void_p).value
