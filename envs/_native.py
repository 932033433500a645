"""Build and load the C ports of the compiled kernels, where a C compiler is at hand.

The package's numerics are numba kernels; numba compiles them on a machine's first use
(the DEKF's about 30 CPU-s) and every process pays for importing numba and loading its
cache (most of a short command), where a C compiler builds the same arithmetic in under
a second and a loaded library costs nothing more. A kernel with a C port (a
``_<name>_native.c`` beside its numba kernels, in any subpackage: the estimators'
members, the LPV simulation of :mod:`~manualcontrol.envs.dynamics`; the same numbers bit
for bit, held so by its tests) runs it wherever :func:`native_library` gives the built
library, and its numba kernels elsewhere: which one ran never shows in a number. The
builder lives in ``envs``, the lowest layer, so that every subpackage above can use it.

The library is built on first use, or at install (``manualcontrol compile``), with the
system C compiler (``$CC``, its words a command such as ``ccache cc``, else ``cc``) and
the flags of :data:`FLAGS`, into the kernel cache: numba's (``$NUMBA_CACHE_DIR``) where
one is set, else the source's ``__pycache__`` folder beside numba's own files, else
``~/.cache/manualcontrol`` (the next where one cannot be written, or its library cannot
be loaded). Its file name carries a hash of the source, the flags, the compiler and its
target and the platform, so an edited source, another compiler or another machine
sharing the folder builds anew, and a build is written under a temporary name and
renamed into place, so a failed or interrupted build leaves nothing half-written (two
processes building at once each rename a whole library).

A CPython extension (:func:`native_extension`: the estimators' online fast path,
``estimators/_online_native.c``) is built the same way with Python's headers added,
where they are installed, and loaded as a module; where it is not built its caller's
Python path runs, with the same numbers.

Where no compiler is found or the build fails, the numba kernels run: the same
numbers, after their compile. ``MANUALCONTROL_NATIVE=0`` runs the numba kernels
everywhere (to compare the two, or where a compiler misbehaves).
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import importlib.machinery
import importlib.util
import os
import platform
import re
import shlex
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "FLAGS",
    "NativeBuildError",
    "array_address",
    "build_library",
    "check_port",
    "local_headers",
    "native_enabled",
    "native_extension",
    "native_failure",
    "native_library",
]

#: IEEE semantics as numba keeps them without fastmath: no reassociation, no fused
#: multiply-add (GCC fuses by default in its GNU modes, clang within a statement).
FLAGS: tuple[str, ...] = (
    "-std=c99",
    "-O2",
    "-fno-fast-math",
    "-ffp-contract=off",
    "-fPIC",
    "-shared",
)

#: Libraries and extensions loaded in this process, and why one could not be built (a
#: library by its source's path, an extension by :func:`_extension_key`).
_LOADED: dict[str, Any] = {}
_FAILED: dict[str, str] = {}


class NativeBuildError(RuntimeError):
    """The C compiler could not build a kernel library (its own message included)."""


def native_enabled() -> bool:
    """Whether C ports may run (``MANUALCONTROL_NATIVE`` is not ``0``)."""
    return os.environ.get("MANUALCONTROL_NATIVE", "1").strip() != "0"


def _compiler() -> list[str] | None:
    """The compiler command: ``$CC`` (words, e.g. ``ccache cc``), else ``cc``; None if absent."""
    for command in (shlex.split(os.environ.get("CC", "")), ["cc"]):
        if command:
            found = shutil.which(command[0])
            if found is not None:
                return [found, *command[1:]]
    return None


def _compiler_identity(compiler: list[str]) -> str:
    """What a build depends on besides its source and flags: compiler, target, platform.

    Asked of the compiler once a process (each C port's first use would otherwise pay
    two compiler processes).
    """
    return _identity_of(tuple(compiler), platform.machine())


@functools.lru_cache(maxsize=8)
def _identity_of(compiler: tuple[str, ...], machine: str) -> str:
    words = [sys.platform, machine, str(ctypes.sizeof(ctypes.c_void_p))]
    for option in ("--version", "-dumpmachine"):
        try:
            done = subprocess.run(
                [*compiler, option], capture_output=True, text=True, timeout=30, check=False
            )
        except (OSError, subprocess.SubprocessError):
            continue
        words.append(done.stdout.strip())
    return "\0".join(words)


def _suffix() -> str:
    if sys.platform == "darwin":
        return ".dylib"
    return ".dll" if sys.platform == "win32" else ".so"


def _cache_folders(source: Path) -> list[Path]:
    """Where a built library may be kept, in order of preference (module docstring)."""
    folders = []
    numba_cache = os.environ.get("NUMBA_CACHE_DIR")
    if numba_cache:
        folders.append(Path(numba_cache) / "manualcontrol-native")
    folders.append(source.parent / "__pycache__")
    try:
        folders.append(Path.home() / ".cache" / "manualcontrol")
    except RuntimeError:  # no home folder (a container's arbitrary user)
        pass
    return folders


def local_headers(source: Path) -> list[Path]:
    """The headers ``source`` includes by ``#include "name"``, beside it: part of its build.

    A port's shared helpers live in such a header (``_native_common.h``); an edit there
    must rebuild every port that includes it, as an edit of the port itself does.
    """
    names = re.findall(r'^\s*#\s*include\s+"([^"]+)"', source.read_text(), re.M)
    return [source.parent / name for name in names]


def build_library(
    source: Path,
    compiler: list[str],
    folder: Path,
    extra_flags: tuple[str, ...] = (),
    suffix: str | None = None,
) -> Path:
    """Build ``source`` with ``compiler`` into ``folder`` (atomically); the library's path.

    The name carries a hash of the source and its local headers (:func:`local_headers`),
    :data:`FLAGS` and ``extra_flags``, the compiler's command, version and target and
    the platform; a library of that name already there is the same build and is
    returned as it is. ``suffix`` ends its name (default: the platform's shared
    library's). Raises :class:`NativeBuildError` with the compiler's message where it
    fails or does not finish in five minutes.
    """
    digest = hashlib.sha256()
    digest.update(source.read_bytes())
    for header in local_headers(source):
        digest.update(header.read_bytes())
    digest.update("\0".join((*FLAGS, *extra_flags, *compiler)).encode())
    digest.update(_compiler_identity(compiler).encode())
    ending = _suffix() if suffix is None else suffix
    target = folder / f"lib{source.stem}-{digest.hexdigest()[:16]}{ending}"
    if target.is_file():
        return target
    folder.mkdir(parents=True, exist_ok=True)
    handle, partial = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".part", dir=folder)
    os.close(handle)
    try:
        try:
            done = subprocess.run(
                [*compiler, *FLAGS, *extra_flags, str(source), "-o", partial, "-lm"],
                capture_output=True,
                text=True,
                timeout=300,
                check=False,
            )
        except subprocess.TimeoutExpired:
            raise NativeBuildError(
                f"{compiler[0]} did not build {source.name} within 300 s"
            ) from None
        if done.returncode != 0:
            message = (done.stderr or done.stdout).strip().splitlines()
            raise NativeBuildError(
                f"{compiler[0]} could not build {source.name} (exit code {done.returncode}): "
                + (message[-1] if message else "no message")
            )
        os.replace(partial, target)
    except BaseException:
        Path(partial).unlink(missing_ok=True)
        raise
    return target


def native_library(source: Path) -> ctypes.CDLL | None:
    """The built library of the C source file ``source`` (a path, in any folder), or None.

    None where C ports are disabled (``MANUALCONTROL_NATIVE=0``), no compiler is found
    or the build failed (:func:`native_failure` says why); the numba kernels then run.
    Built once per cache and loaded once per process.
    """
    return _built(
        Path(source),
        str(source),
        (),
        None,
        lambda path: ctypes.CDLL(str(path)),
        "the numba kernels run, compiled at first use",
    )


def native_extension(source: Path, name: str) -> Any:
    """The CPython extension module ``name`` built from ``source``, or None.

    As :func:`native_library`, with Python's own headers (``Python.h``, which a Python
    installed without its development files lacks) and the interpreter's extension
    suffix; ``source`` defines ``PyInit_<last part of name>``. It is loaded as that
    module (not entered in ``sys.modules``). Where it is None (:func:`native_failure`
    with ``extension=name`` says why) the caller's Python path runs: the same numbers,
    slower. Not built for a free-threaded Python, whose GIL a module of this kind
    would turn back on.
    """
    if not native_enabled():
        return None
    source = Path(source)
    key = _extension_key(source, name)
    module = _LOADED.get(key)
    if module is not None or key in _FAILED:
        return module
    fallback = "the Python path runs"
    if sysconfig.get_config_var("Py_GIL_DISABLED"):
        _FAILED[key] = f"a free-threaded Python: {fallback}"
        return None
    paths = sysconfig.get_paths()
    includes = list(dict.fromkeys(paths.get(k) for k in ("include", "platinclude")))
    if not includes[0] or not (Path(includes[0]) / "Python.h").is_file():
        _FAILED[key] = f"Python's headers (Python.h) are not installed: {fallback}"
        return None
    flags = tuple(f"-I{folder}" for folder in includes if folder)
    if sys.platform == "darwin":  # Python's symbols are the interpreter's, found at load
        flags += ("-undefined", "dynamic_lookup")

    def load(path: Path) -> Any:
        loader = importlib.machinery.ExtensionFileLoader(name, str(path))
        spec = importlib.util.spec_from_file_location(name, str(path), loader=loader)
        module = importlib.util.module_from_spec(spec)
        try:
            loader.exec_module(module)
        except Exception as error:  # an init that raises or fails: not loadable
            raise ImportError(f"{type(error).__name__}: {error}") from error
        return module

    return _built(source, key, flags, importlib.machinery.EXTENSION_SUFFIXES[0], load, fallback)


def _extension_key(source: Path, name: str) -> str:
    """The extension's key in the loaded and failed builds (a library's is its path)."""
    return f"{source}\0extension {name}"


def _built(
    source: Path,
    key: str,
    extra_flags: tuple[str, ...],
    suffix: str | None,
    load: Any,
    fallback: str,
) -> Any:
    """``source`` built (:func:`build_library`) and loaded by ``load``, once a process; or None.

    ``key`` names the build in :data:`_LOADED` and :data:`_FAILED` (a library and an
    extension of one source are two builds).
    """
    if not native_enabled():
        return None
    library = _LOADED.get(key)
    if library is not None or key in _FAILED:
        return library
    compiler = _compiler()
    if compiler is None:
        _FAILED[key] = f"no C compiler found ($CC or cc): {fallback}"
        return None
    errors = []
    for folder in _cache_folders(source):
        try:
            path = build_library(source, compiler, folder, extra_flags, suffix)
        except NativeBuildError as error:
            errors.append(str(error))
            break  # the compiler's verdict does not depend on the folder
        except OSError as error:  # a folder we may not write: try the next
            errors.append(f"{folder}: {error}")
            continue
        try:
            library = load(path)
        except (OSError, ImportError) as error:  # built but not loadable (noexec): the next
            errors.append(f"{path} does not load: {error}")
            continue
        _LOADED[key] = library
        return library
    _FAILED[key] = "; ".join(errors) + f": {fallback}"
    return None


def native_failure(source: Path, extension: str | None = None) -> str:
    """Why :func:`native_library` gave None for ``source`` in this process ('' if not).

    With ``extension``, why :func:`native_extension` gave None for that module.
    """
    if not native_enabled():
        ran = "the numba kernels run" if extension is None else "the Python path runs"
        return f"MANUALCONTROL_NATIVE=0: {ran}"
    key = str(source) if extension is None else _extension_key(Path(source), extension)
    return _FAILED.get(key, "")


# ------------------------------------------------------------------ the bindings' checks


def check_port(
    lib: ctypes.CDLL,
    prefix: str,
    source: str,
    layout: int,
    sizes: dict[str, int],
    constants: list[float],
) -> None:
    """Check a loaded C port against its binding and the Python modules, or raise.

    ``<prefix>_abi()`` must return the binding's ``layout``, each ``<prefix>_<name>()``
    of ``sizes`` the size of the binding's struct of that name, and
    ``<prefix>_constants()`` the values of ``constants`` (the ``CFG_*``, ``SC_*``, codes
    and tolerances the C repeats): a C edit without the Python one, or the reverse,
    raises ``RuntimeError`` naming what differs before any number is computed.
    """
    int64, address = ctypes.c_int64, ctypes.c_void_p
    abi = getattr(lib, f"{prefix}_abi")
    abi.restype = int64
    found = {}
    for name in sizes:
        function = getattr(lib, f"{prefix}_{name}")
        function.restype = int64
        found[name] = function()
    if abi() != layout or found != sizes:
        raise RuntimeError(
            f"{source}'s structs (layout {abi()}, sizes {found}) differ from its binding's "
            f"(layout {layout}, sizes {sizes}): edit the two together"
        )
    count = getattr(lib, f"{prefix}_constants")
    count.argtypes = [address]
    count.restype = int64
    values = np.zeros(count(None))
    count(values.ctypes.data)
    expected = [float(v) for v in constants]
    if values.tolist() != expected:
        raise RuntimeError(
            f"{source}'s constants {values.tolist()} differ from the Python modules' "
            f"{expected}: edit the two together"
        )


_KINDS = {"f": np.float64, "i": np.int64, "b": np.bool_}


def array_address(
    member: str,
    name: str,
    array: Any,
    shape: tuple | None,
    keep: list,
    dtype: Any = None,
) -> int:
    """The address of a record field's data for a C struct, the array checked and kept alive.

    The C port reads ``array`` as C-contiguous ``dtype`` (default: float64, int64 or
    bool by its kind) of ``shape`` (None: any); anything else raises naming the
    ``member``'s field. ``keep`` holds the array as long as the struct points into it.
    """
    if not isinstance(array, np.ndarray):
        raise TypeError(f"the {member}'s record field {name} is not an array")
    kind = _KINDS.get(array.dtype.kind) if dtype is None else np.dtype(dtype)
    if kind is None or array.dtype != kind or not array.flags.c_contiguous:
        wanted = "float64, int64 or bool" if dtype is None else np.dtype(dtype).name
        raise ValueError(
            f"the {member}'s record field {name} is {array.dtype}"
            f"{'' if array.flags.c_contiguous else ', not C-contiguous'}: the C port "
            f"reads it as C-contiguous {wanted}"
        )
    if shape is not None and array.shape != shape:
        raise ValueError(
            f"the {member}'s record field {name} has shape {array.shape}, the C port reads {shape}"
        )
    keep.append(array)
    return array.ctypes.data if array.size else 0
