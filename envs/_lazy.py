"""A package's public names, imported from their modules on first use (PEP 562).

A package ``__init__`` that imported every member would make ``import
manualcontrol.estimators`` pay for scipy.signal, every compiled kernel and the pilot
models before any of them is used. Instead it lists where each public name lives and
hands :func:`lazy_exports`' two functions to Python as the module's ``__getattr__``
and ``__dir__``: ``from manualcontrol.estimators import DEKF`` imports
``manualcontrol.estimators.members.dekf`` then, and only then, and the name is the very
object that module defines. A name imported once is kept in the package's namespace,
so later lookups cost a dictionary read.
"""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Callable, Mapping, MutableMapping, Sequence
from typing import Any

__all__ = ["LazyKernel", "has_kernel", "kernels_on_first_use", "lazy_exports"]


def lazy_exports(
    namespace: MutableMapping[str, Any], exports: Mapping[str, Sequence[str]]
) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """The ``__getattr__`` and ``__dir__`` of a package that exports names lazily.

    ``namespace`` is the package's ``globals()``; ``exports`` maps each module (its
    full name) to the public names it defines. A name not listed is an
    :class:`AttributeError`, as for any module (which is also how ``from package
    import submodule`` falls back to importing the submodule).
    """
    package = namespace["__name__"]
    home = {name: module for module, names in exports.items() for name in names}

    def get_attribute(name: str) -> Any:
        module = home.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(module), name)
        namespace[name] = value
        return value

    def names() -> list[str]:
        return sorted({*namespace, *home})

    return get_attribute, names


def kernels_on_first_use(
    namespace: MutableMapping[str, Any], module: str, names: Sequence[str]
) -> Callable[[str], Any]:
    """The ``__getattr__`` of a numba-free module whose numba kernels live in ``module``.

    A module that keeps the record layouts, constants and builders a C port needs moves
    its numba kernels to a kernel module (its full name, ``module``) that only the
    fallback imports; this keeps them importable from the old home: ``names`` are
    imported from ``module`` on first use (PEP 562) and kept in ``namespace``.
    """
    home = namespace["__name__"]
    kernels = frozenset(names)

    def get_attribute(name: str) -> Any:
        if name not in kernels:
            raise AttributeError(f"module {home!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(module), name)
        namespace[name] = value
        return value

    return get_attribute


class LazyKernel:
    """A class attribute naming a numba kernel, imported from its module on first read.

    ``_step_kernel = LazyKernel("manualcontrol.x._kernels", "step")`` reads as the kernel
    (the dispatcher itself, as ``staticmethod(step)`` did) on the class and on its
    instances, but imports the kernel module (and numba) only when first read: a filter
    whose C port runs never reads it.
    """

    def __init__(self, module: str, name: str) -> None:
        self.module = module
        self.name = name
        self._kernel: Any = None

    def __get__(self, instance: Any, owner: type | None = None) -> Any:
        kernel = self._kernel
        if kernel is None:
            kernel = self._kernel = getattr(importlib.import_module(self.module), self.name)
        return kernel

    def __repr__(self) -> str:
        return f"LazyKernel({self.module!r}, {self.name!r})"


def has_kernel(owner: type, name: str) -> bool:
    """Whether class ``owner`` names a kernel ``name`` (not None), without importing it.

    Reading a :class:`LazyKernel` imports its kernel module and numba; asking whether a
    member has a batched step (the C port may run it) must not.
    """
    return inspect.getattr_static(owner, name, None) is not None
