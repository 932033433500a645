"""Keep numba's on-disk caches of the package's kernels in step with their sources.

numba keys a cached kernel on its *own* source file only: when a kernel it calls (the
shared Kalman algebra in ``estimators/filters``, the LPV step in ``envs/dynamics``) is
edited, the caller's cached machine code still holds the old callee, and runs it
silently. That happens to anyone working on an editable install (``make demo`` after a
``git pull`` that changed only a shared kernel). So on import the package compares a
stamp of its kernel sources (path, size and modification time of every ``.py`` file of
the five subpackages that imports numba or compiles a kernel with it) with the one the
last import left; when they differ, it deletes the package's cached kernels
(``__pycache__/*.nbi``, ``*.nbc``) and numba compiles afresh.
A fresh clone or install has no stamp and nothing to delete. Any failure here (a
read-only install, a race between processes) leaves the caches alone: numba then
behaves as it always did.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import re
from collections.abc import Iterable
from pathlib import Path

__all__ = ["PACKAGES", "refresh_kernel_cache", "source_stamp"]

#: The subpackages whose modules hold compiled kernels that call one another.
PACKAGES = ("envs", "pilots", "estimators", "agents", "bench")
_STAMP = "manualcontrol-kernel-sources.stamp"
#: What marks a kernel source: a file that imports or compiles with numba, not one that
#: only mentions it (a kernel may be built with ``vectorize``, ``cfunc``, ``overload``).
_KERNEL = re.compile(rb"^\s*(?:import numba\b|from numba\b)|numba\.n?jit\b|^\s*@n?jit\b", re.M)


def _roots() -> list[Path]:
    roots = [Path(__file__).resolve().parent]
    for name in PACKAGES[1:]:
        spec = importlib.util.find_spec(f"manualcontrol.{name}")
        if spec is not None and spec.submodule_search_locations:
            roots.extend(Path(p) for p in spec.submodule_search_locations)
    return roots


def source_stamp(roots: Iterable[Path]) -> str:
    """Digest of the path, size and modification time of each kernel source under ``roots``.

    Kernel sources are the ``.py`` files that import numba or compile with it
    (:data:`_KERNEL`); editing any other file, one that only mentions numba included,
    keeps the caches.
    """
    digest = hashlib.sha256()
    for root in roots:
        for path in sorted(Path(root).rglob("*.py")):
            if "__pycache__" in path.parts or not _KERNEL.search(path.read_bytes()):
                continue
            status = path.stat()
            digest.update(f"{path}\0{status.st_size}\0{status.st_mtime_ns}\n".encode())
    return digest.hexdigest()


def refresh_kernel_cache(roots: Iterable[Path] | None = None) -> bool:
    """Delete the cached kernels under ``roots`` if their sources changed; True if so."""
    try:
        roots = list(_roots() if roots is None else roots)
        stamp = source_stamp(roots)
        stamp_file = roots[0] / "__pycache__" / _STAMP
        if stamp_file.is_file() and stamp_file.read_text() == stamp:
            return False
        for root in roots:
            for cached in (*root.rglob("*.nbi"), *root.rglob("*.nbc")):
                try:
                    cached.unlink()
                except OSError:
                    pass
        stamp_file.parent.mkdir(exist_ok=True)
        temporary = stamp_file.with_name(f"{_STAMP}.{os.getpid()}.part")
        temporary.write_text(stamp)
        os.replace(temporary, stamp_file)
        return True
    except OSError:
        return False
