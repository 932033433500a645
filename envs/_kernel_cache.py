"""Keep numba's on-disk caches of the package's kernels in step with their sources.

numba keys a cached kernel on its *own* source file only: when a kernel it calls (the
shared Kalman algebra in ``estimators/filters``, the LPV step in ``envs/dynamics``) is
edited, the caller's cached machine code still holds the old callee, and runs it
silently. That happens to anyone working on an editable install (``make demo`` after a
``git pull`` that changed only a shared kernel). So on import the package stamps each
*kernel module* (a ``.py`` file of the five subpackages that imports numba or compiles a
kernel with it, :data:`_KERNEL`) with the path, size and modification time of itself
and of every kernel module it depends on, compares the stamps with those the last
import left, and deletes the cached kernels of exactly the modules whose stamp changed,
is new or is gone (numba's ``__pycache__/<stem>.<qualname>-<line>.py<ver>.nbi`` and
``.<n>.nbc`` next to the source, and in the folder numba takes for it under every
``NUMBA_CACHE_DIR`` the record has seen, so that a run with the variable and one
without keep each other's caches in step; a value never seen is emptied once); numba
compiles those afresh and loads the others.

What counts as a dependency. Module M depends on every package module it names: an
``import`` or ``from ... import`` anywhere in its file (at the top, in a function, under
``TYPE_CHECKING``; absolute or relative; ``from P import n`` names ``P`` and, when it
is one, the submodule ``P.n``), and a string constant that is exactly a package
module's full name (``"manualcontrol.x.y"``), which is how the lazily exporting package
initialisers name the modules their public names come from. An entry point
(``"manualcontrol.x.y:Attr"``, the Gymnasium ids) is not a dependency: a loader builds
a Python object from it, no kernel imports it. The dependencies are followed
transitively through *every* package module, since a kernel often reaches a callee
through a module that compiles nothing (a package initialiser re-exporting it, a
facade), but only the *kernel* modules reached enter the stamp: numba compiles code
from kernel modules alone, so a module that compiles nothing cannot put code into a
cached kernel, and editing one (a docstring, an env, a CLI) keeps every cache. The one
thing it could put there is a global constant a compiled function reads, which numba
freezes at compile time; no compiled function of the package reads a name imported
from a module that compiles nothing, unless that module declares itself a kernel
module by the line :data:`CONSTANTS_MARKER` (a numba-free module that holds the record
layouts and constants both its kernels and the C ports read, so a process on the C
path never imports numba; keep it so: put such a constant in a kernel module or mark
its module). Importing ``a.b.c`` does not name the packages ``a`` and ``a.b`` whose
initialisers Python runs first: a kernel uses what it imports, and counting them would
tie kernels together through package initialisers they never use. A module loaded by
a name built at run time (``importlib.import_module(f"...{x}")``) is not seen.

Cost: this runs at every ``import manualcontrol.envs``. The record (one JSON file next
to the old stamp file, written atomically) keeps, per source file, its size, its
modification time, whether it is a kernel module and the package modules it names, so
an import reads and parses only the files that changed since the last one; the rest is
a directory walk and one ``stat`` per file.

A fresh clone or install has no record: every kernel module is new and the cached
kernels under the roots, if any, are dropped (none are there). Any failure here (a
read-only install, a race between processes) leaves the caches alone and keeps the
record as it was: numba then behaves as it always did, and the next import tries again.
"""

from __future__ import annotations

import ast
import hashlib
import importlib.util
import json
import os
import re
from collections.abc import Iterable, Mapping
from pathlib import Path

__all__ = ["PACKAGES", "kernel_closures", "kernel_stamps", "refresh_kernel_cache"]

#: The subpackages whose modules hold compiled kernels that call one another.
PACKAGES = ("envs", "pilots", "estimators", "agents", "bench")
_RECORD = "manualcontrol-kernel-sources.json"
_OLD_STAMP = "manualcontrol-kernel-sources.stamp"  # the single stamp of earlier versions
_FORMAT = 1
#: What marks a kernel source: a file that imports or compiles with numba, not one that
#: only mentions it (a kernel may be built with ``vectorize``, ``cfunc``, ``overload``).
#: A line that makes a module a kernel module without numba: numba kernels read its globals.
CONSTANTS_MARKER = "# numba kernels read this module's constants"
_KERNEL = re.compile(
    rb"^\s*(?:import numba\b|from numba\b)|numba\.n?jit\b|^\s*@n?jit\b"
    rb"|^# numba kernels read this module's constants$",
    re.M,
)
#: A string constant that is a package module's full name (a lazy export's home).
_MODULE_NAME = re.compile(r"manualcontrol(?:\.[A-Za-z_]\w*)+")
#: A numba cache file: ``[prefix-]<file stem>.<qualname>-<line>.py<ver>.nbi`` or
#: ``....<n>.nbc`` (``<locals>`` loses its brackets; gufunc wrappers take ``guf-``).
_CACHED = re.compile(r"(?:[^.\-]+-)?([^.\-]+)\..*\.nb[ic]")

#: A source file's record: size, modification time, kernel module or not, names it
#: imports (full module names, ``manualcontrol.`` ones only).
_Entry = tuple[int, int, bool, list[str]]


def _roots() -> list[Path]:
    # the path as imported, as numba hashes it for NUMBA_CACHE_DIR (symlinks kept)
    roots = [Path(os.path.abspath(__file__)).parent]
    for name in PACKAGES[1:]:
        spec = importlib.util.find_spec(f"manualcontrol.{name}")
        if spec is not None and spec.submodule_search_locations:
            roots.extend(Path(p) for p in spec.submodule_search_locations)
    return roots


def _is_kernel_source(text: bytes) -> bool:
    """Whether ``text`` matches :data:`_KERNEL` (numba, or :data:`CONSTANTS_MARKER`).

    Every form it matches names ``numba`` or ``jit``, so a file naming neither is
    passed over without the regular expression, which is slow on a file it does not
    match (tries a match at every line).
    """
    return (b"numba" in text or b"jit" in text) and _KERNEL.search(text) is not None


def _modules(roots: Iterable[Path]) -> dict[str, str]:
    """Each source file under ``roots`` by its module name.

    A root is the folder of the subpackage ``manualcontrol.<its folder name>``, as the
    package's folders are laid out (``envs`` holds ``manualcontrol.envs``).
    """
    modules: dict[str, str] = {}
    for root in roots:
        root = str(root)
        package = f"manualcontrol.{os.path.basename(root)}"
        for folder, folders, files in os.walk(root):
            folders[:] = sorted(f for f in folders if f != "__pycache__" and f[0] != ".")
            relative = os.path.relpath(folder, root)
            prefix = package if relative == "." else f"{package}.{relative.replace(os.sep, '.')}"
            for name in sorted(files):
                if name.endswith(".py"):
                    stem = name[:-3]
                    module = prefix if stem == "__init__" else f"{prefix}.{stem}"
                    modules.setdefault(module, os.path.join(folder, name))
    return modules


def _imports(text: bytes, module: str, is_package: bool) -> list[str]:
    """The ``manualcontrol`` modules a source names (some may be other things)."""
    try:
        tree = ast.parse(text)
    except (SyntaxError, ValueError):  # mid-edit: its next save is parsed again
        return []
    package = module if is_package else module.rpartition(".")[0]
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                if node.level - 1 >= len(parts):
                    continue
                parent = ".".join(parts[: len(parts) - (node.level - 1)])
                base = f"{parent}.{base}" if base else parent
            names.add(base)
            names.update(f"{base}.{alias.name}" for alias in node.names if alias.name != "*")
        elif isinstance(node, ast.Constant) and isinstance(node.value, str):
            if _MODULE_NAME.fullmatch(node.value):
                names.add(node.value)
    return sorted(n for n in names if n.startswith("manualcontrol."))


def _scan(modules: Mapping[str, str], known: Mapping[str, _Entry]) -> dict[str, _Entry]:
    """Each source file's record; a file whose size and mtime are as ``known`` is not read."""
    entries: dict[str, _Entry] = {}
    for module, path in modules.items():
        status = os.stat(path)
        entry = known.get(path)
        if entry is None or (entry[0], entry[1]) != (status.st_size, status.st_mtime_ns):
            with open(path, "rb") as source:
                text = source.read()
            is_package = os.path.basename(path) == "__init__.py"
            entry = (
                status.st_size,
                status.st_mtime_ns,
                _is_kernel_source(text),
                _imports(text, module, is_package),
            )
        entries[path] = entry
    return entries


def _closures(modules: Mapping[str, str], entries: Mapping[str, _Entry]) -> dict[str, list[str]]:
    """Each kernel module and the kernel modules it depends on, itself excluded."""
    edges = {
        path: {modules[name] for name in entries[path][3] if name in modules} for path in entries
    }
    closures: dict[str, list[str]] = {}
    for start, entry in entries.items():
        if not entry[2]:
            continue
        seen, todo = {start}, [start]
        while todo:
            for callee in edges[todo.pop()] - seen:
                seen.add(callee)
                todo.append(callee)
        closures[start] = sorted(p for p in seen - {start} if entries[p][2])
    return closures


def _stamps(closures: Mapping[str, list[str]], entries: Mapping[str, _Entry]) -> dict[str, str]:
    stamps = {}
    for path, callees in closures.items():
        digest = hashlib.sha256()
        for source in (path, *callees):
            size, mtime_ns = entries[source][:2]
            digest.update(f"{source}\0{size}\0{mtime_ns}\n".encode())
        stamps[path] = digest.hexdigest()
    return stamps


def _state(
    roots: Iterable[Path], known: Mapping[str, _Entry]
) -> tuple[dict[str, _Entry], dict[str, list[str]]]:
    modules = _modules(roots)
    entries = _scan(modules, known)
    return entries, _closures(modules, entries)


def _given(roots: Iterable[Path] | None) -> list[Path]:
    return [Path(r) for r in (_roots() if roots is None else roots)]


def kernel_closures(roots: Iterable[Path] | None = None) -> dict[Path, list[Path]]:
    """Each kernel module under ``roots`` and the kernel modules it depends on.

    ``roots`` are the subpackages' folders (the installed package's by default).
    """
    _, closures = _state(_given(roots), {})
    return {Path(p): [Path(c) for c in callees] for p, callees in closures.items()}


def kernel_stamps(roots: Iterable[Path] | None = None) -> dict[str, str]:
    """Each kernel module's stamp, by its path.

    A digest of the path, size and modification time of the module and of every kernel
    module it depends on; editing any other file keeps them.
    """
    entries, closures = _state(_given(roots), {})
    return _stamps(closures, entries)


def _read_record(
    path: Path,
) -> tuple[dict[str, _Entry], dict[str, str], list[str]] | None:
    try:
        record = json.loads(path.read_text())
        if record.get("format") != _FORMAT:
            return None
        files = {
            p: (int(s), int(m), bool(k), list(i)) for p, (s, m, k, i) in record["files"].items()
        }
        return files, dict(record["stamps"]), [str(u) for u in record.get("user_caches", [])]
    except FileNotFoundError:
        return None
    except (ValueError, TypeError, KeyError, AttributeError):  # not ours, or torn
        return None


def _user_cache() -> str | None:
    """The ``NUMBA_CACHE_DIR`` numba would use in this process (absolute), or None."""
    user = os.environ.get("NUMBA_CACHE_DIR")
    return os.path.abspath(user) if user else None


def _cache_folders(folder: str, user_caches: Iterable[str]) -> list[str]:
    """Where numba keeps the cached kernels of the modules in source ``folder``.

    ``folder/__pycache__`` (numba's in-tree locator), and under each of ``user_caches``
    (the ``NUMBA_CACHE_DIR`` values the record has seen) the folder numba's
    user-provided locator takes there: the source folder's name and the SHA-1 of its
    absolute path (``numba.core.caching``'s ``get_suitable_cache_subpath``, rebuilt here
    because importing numba would cost every numba-free path).
    """
    source = os.path.abspath(folder)
    subpath = f"{os.path.basename(source)}_{hashlib.sha1(source.encode()).hexdigest()}"
    return [os.path.join(folder, "__pycache__")] + [os.path.join(u, subpath) for u in user_caches]


def _drop(sources: Iterable[str], user_caches: Iterable[str]) -> None:
    """Delete the cached kernels of ``sources``; raise OSError if one cannot be."""
    stems: dict[str, set[str]] = {}
    for source in sources:
        folder, name = os.path.split(source)
        for cache in _cache_folders(folder, user_caches):
            stems.setdefault(cache, set()).add(name[:-3])
    for cache, names in stems.items():
        try:
            entries = os.listdir(cache)
        except FileNotFoundError:
            continue
        for entry in entries:
            match = _CACHED.fullmatch(entry)
            if match and match.group(1) in names:
                try:
                    os.unlink(os.path.join(cache, entry))
                except FileNotFoundError:  # another process dropped it first
                    pass


def _drop_all(roots: Iterable[Path], user_caches: Iterable[str], in_tree: bool = True) -> None:
    """Delete every cached kernel under ``roots`` (:func:`_cache_folders`; the tree's too)."""
    user_caches = list(user_caches)
    for root in roots:
        for folder, subfolders, _ in os.walk(root):
            subfolders[:] = [f for f in subfolders if f != "__pycache__" and f[0] != "."]
            for cache in _cache_folders(folder, user_caches)[0 if in_tree else 1 :]:
                for cached in (*Path(cache).glob("*.nbi"), *Path(cache).glob("*.nbc")):
                    try:
                        cached.unlink()
                    except FileNotFoundError:
                        pass


def refresh_kernel_cache(roots: Iterable[Path] | None = None) -> bool:
    """Delete the cached kernels of the modules under ``roots`` whose stamp changed.

    True if some were dropped: a kernel module's stamp changed or is new, or a kernel
    module is gone (a fresh clone, all of them new, included); False if every stamp is
    as the last import left it, or on any OSError (nothing then is deleted or recorded).
    """
    try:
        roots = _given(roots)
        cache = roots[0] / "__pycache__"
        record_file = cache / _RECORD
        if not os.access(cache if cache.is_dir() else roots[0], os.W_OK):
            return False  # a read-only install: nothing can be deleted, nor recorded
        previous = _read_record(record_file)
        entries, closures = _state(roots, previous[0] if previous else {})
        stamps = _stamps(closures, entries)
        # every NUMBA_CACHE_DIR seen is kept in step: a run without it (or with another)
        # must not leave stale kernels where a later run with it looks. One since removed
        # holds nothing stale and is forgotten (a run with it again finds it never seen
        # and empties it once); else every temporary folder ever given stayed listed
        user = _user_cache()
        known = previous[2] if previous else []
        # (this run's own is kept: numba creates it only when it first writes there)
        kept = [u for u in known if u == user or os.path.isdir(u)]
        user_caches = sorted({*kept, user} - {None})
        if previous is None:  # nothing tells which caches are current: drop them all
            _drop_all(roots, user_caches)
            changed = True
        else:
            old = previous[1]
            stale = {p for p in stamps.keys() | old.keys() if stamps.get(p) != old.get(p)}
            _drop(stale, user_caches)
            changed = bool(stale)
            if user is not None and user not in known:  # never kept in step: drop it all
                _drop_all(roots, [user], in_tree=False)
                changed = True
            if not changed and entries == previous[0] and len(kept) == len(known):
                return False
        record = {
            "format": _FORMAT,
            "files": {p: list(e) for p, e in sorted(entries.items())},
            "stamps": dict(sorted(stamps.items())),
            "user_caches": user_caches,
        }
        cache.mkdir(exist_ok=True)
        temporary = cache / f"{_RECORD}.{os.getpid()}.part"
        temporary.write_text(json.dumps(record, separators=(",", ":")))
        os.replace(temporary, record_file)
        if previous is None:
            try:
                (cache / _OLD_STAMP).unlink()
            except FileNotFoundError:
                pass
        return changed
    except OSError:
        return False
