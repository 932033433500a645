"""A kernel module's numba caches are dropped when it or a kernel it depends on changes."""

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from manualcontrol.envs import _kernel_cache
from manualcontrol.envs._kernel_cache import kernel_closures, kernel_stamps, refresh_kernel_cache

#: A fake subpackage ``manualcontrol.kernels``: kernel modules and the ones they import.
SOURCES = {
    # the shared algebra: a leaf kernel module
    "linalg.py": "import numba\n\n@numba.njit\ndef solve(): pass\n",
    # imports it directly
    "kalman.py": (
        "import numba\nfrom manualcontrol.kernels.linalg import solve\n\n"
        "@numba.njit\ndef correct(): solve()\n"
    ),
    # a module that compiles nothing, re-exporting it
    "api.py": "from manualcontrol.kernels.linalg import solve\n\n__all__ = ['solve']\n",
    # imports it through that module
    "member.py": (
        "from numba import njit\n\nfrom manualcontrol.kernels.api import solve\n\n"
        "@njit\ndef step(): solve()\n"
    ),
    # a package exporting it lazily, by the module's name, and a kernel using that
    "lazy/__init__.py": "EXPORTS = {'manualcontrol.kernels.linalg': ('solve',)}\n",
    "lazy/user.py": (
        "import numba\n\ndef make():\n    from manualcontrol.kernels.lazy import solve\n"
        "    return numba.njit(lambda: solve())\n"
    ),
    # a relative import
    "lazy/relative.py": "import numba\n\nfrom ..linalg import solve\n",
    # unrelated kernels, one compiled in a closure (its cache file names ``locals``)
    "other.py": (
        "import numba\n\ndef make():\n    @numba.njit\n    def inner(): pass\n    return inner\n"
    ),
    # names numba without compiling with it, and names a module only as an entry point
    "cli.py": "print('numba is only named here')\nENTRY = 'manualcontrol.kernels.linalg:solve'\n",
}
#: The caches numba leaves next to each kernel module (a gufunc's wrapper is ``guf-``).
CACHES = {
    "linalg.py": ["linalg.solve-4.py311.nbi", "linalg.solve-4.py311.1.nbc"],
    "kalman.py": ["kalman.correct-5.py311.nbi", "guf-kalman.correct-5.py311.nbi"],
    "member.py": ["member.step-6.py311.nbi", "member.step-6.py311.2.nbc"],
    "lazy/user.py": ["user.make.locals.lambda-5.py311.nbi"],
    "lazy/relative.py": ["relative.solve-9.py311.nbi"],
    "other.py": ["other.make.locals.inner-4.py311.nbi", "other.make.locals.inner-4.py311.1.nbc"],
}
DEPENDS_ON_LINALG = ("linalg.py", "kalman.py", "member.py", "lazy/user.py", "lazy/relative.py")


def edit(path, text):
    """Write ``text`` with a modification time surely later than the file's last one."""
    later = (path.stat().st_mtime_ns if path.exists() else 0) + 10**9
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    os.utime(path, ns=(later, later))


def make_package(tmp_path):
    root = tmp_path / "kernels"
    for name, text in SOURCES.items():
        edit(root / name, text)
    return [root]


def cache_all(root):
    for source, names in CACHES.items():
        cache = (root / source).parent / "__pycache__"
        cache.mkdir(exist_ok=True)
        for name in names:
            (cache / name).write_bytes(b"machine code")


def cached(root):
    """The kernel modules (by source) that still have cache files."""
    left = set()
    for source, names in CACHES.items():
        cache = (root / source).parent / "__pycache__"
        if any((cache / name).is_file() for name in names):
            left.add(source)
    return left


@pytest.fixture
def package(tmp_path):
    roots = make_package(tmp_path)
    assert refresh_kernel_cache(roots)  # no record yet: a fresh clone
    cache_all(roots[0])  # then the kernels are compiled and cached
    assert not refresh_kernel_cache(roots)  # nothing changed: caches kept
    assert cached(roots[0]) == set(CACHES)
    return roots


def test_the_closures_follow_imports_through_modules_that_compile_nothing(tmp_path):
    root = make_package(tmp_path)[0]
    closures = {
        str(module.relative_to(root)): {str(c.relative_to(root)) for c in callees}
        for module, callees in kernel_closures([root]).items()
    }
    assert closures == {
        "linalg.py": set(),
        "kalman.py": {"linalg.py"},
        "member.py": {"linalg.py"},
        "lazy/user.py": {"linalg.py"},
        "lazy/relative.py": {"linalg.py"},
        "other.py": set(),
    }


def test_editing_a_kernel_drops_its_caches_and_its_callers_only(package):
    root = package[0]
    edit(root / "linalg.py", SOURCES["linalg.py"] + "# changed\n")
    assert refresh_kernel_cache(package)
    assert cached(root) == set(CACHES) - set(DEPENDS_ON_LINALG)  # other.py kept
    cache_all(root)
    assert not refresh_kernel_cache(package)
    # a caller edited: its callee keeps its caches
    edit(root / "kalman.py", SOURCES["kalman.py"] + "# changed\n")
    assert refresh_kernel_cache(package)
    assert cached(root) == set(CACHES) - {"kalman.py"}


def test_editing_a_file_that_compiles_nothing_keeps_every_cache(package):
    root = package[0]
    stamps = kernel_stamps(package)
    edit(root / "cli.py", SOURCES["cli.py"] + "# numba is named, no kernels\n")
    # even one a kernel reaches its callee through
    edit(root / "api.py", SOURCES["api.py"] + "# a comment\n")
    assert kernel_stamps(package) == stamps
    assert not refresh_kernel_cache(package)
    assert cached(root) == set(CACHES)


def test_a_marked_numba_free_module_of_constants_counts_as_a_kernel_module(tmp_path):
    """Editing the constants a kernel reads from a numba-free, marked module drops its caches."""
    root = make_package(tmp_path)[0]
    edit(root / "layout.py", f"{_kernel_cache.CONSTANTS_MARKER}\nSIZE = 3\n")
    edit(
        root / "stepper.py",
        "import numba\nfrom manualcontrol.kernels.layout import SIZE\n\n"
        "@numba.njit\ndef step(): return SIZE\n",
    )
    closures = {
        str(module.relative_to(root)): {str(c.relative_to(root)) for c in callees}
        for module, callees in kernel_closures([root]).items()
    }
    assert closures["layout.py"] == set() and closures["stepper.py"] == {"layout.py"}
    stamps = kernel_stamps([root])
    edit(root / "layout.py", f"{_kernel_cache.CONSTANTS_MARKER}\nSIZE = 4\n")
    changed = kernel_stamps([root])
    assert {p for p in stamps if stamps[p] != changed[p]} == {
        str(root / "layout.py"),
        str(root / "stepper.py"),
    }


def test_a_new_kernel_module_without_caches_is_fine(package):
    root = package[0]
    edit(root / "ufuncs.py", "import numba as nb\n\nsquare = nb.vectorize(lambda x: x * x)\n")
    assert str(root / "ufuncs.py") in kernel_stamps(package)  # numba under another name
    assert refresh_kernel_cache(package)  # a new stamp
    assert cached(root) == set(CACHES)
    assert not refresh_kernel_cache(package)


def test_a_removed_modules_stale_caches_are_dropped(package):
    root = package[0]
    (root / "other.py").unlink()
    assert refresh_kernel_cache(package)
    assert cached(root) == set(CACHES) - {"other.py"}
    # removing a callee drops its callers too (their closure changed)
    (root / "linalg.py").unlink()
    assert refresh_kernel_cache(package)
    assert cached(root) == set(CACHES) - {"other.py", *DEPENDS_ON_LINALG}


def test_without_a_record_every_cache_under_the_roots_is_dropped(tmp_path):
    # an older checkout's single stamp, caches of a module that is gone
    roots = make_package(tmp_path)
    root = roots[0]
    cache_all(root)
    (root / "__pycache__" / "gone.f-1.py311.nbi").write_bytes(b"old")
    (root / "__pycache__" / "manualcontrol-kernel-sources.stamp").write_text("0" * 64)
    assert refresh_kernel_cache(roots)
    assert not list(root.rglob("*.nb[ic]"))
    assert not (root / "__pycache__" / "manualcontrol-kernel-sources.stamp").exists()
    record = json.loads((root / "__pycache__" / "manualcontrol-kernel-sources.json").read_text())
    assert set(record["stamps"]) == {str(root / name) for name in CACHES}
    # a torn record counts as none
    (root / "__pycache__" / "manualcontrol-kernel-sources.json").write_text('{"form')
    cache_all(root)
    assert refresh_kernel_cache(roots)
    assert cached(root) == set()


def test_only_changed_files_are_parsed_again(package, monkeypatch):
    root = package[0]
    parsed = []
    real = _kernel_cache._imports
    monkeypatch.setattr(
        _kernel_cache, "_imports", lambda text, *args: parsed.append(text) or real(text, *args)
    )
    assert not refresh_kernel_cache(package)
    assert parsed == []
    edit(root / "cli.py", SOURCES["cli.py"] + "# again\n")
    assert not refresh_kernel_cache(package)
    assert len(parsed) == 1


def test_a_place_that_cannot_be_changed_leaves_the_caches_alone(package, monkeypatch):
    root = package[0]
    record = root / "__pycache__" / "manualcontrol-kernel-sources.json"
    before = record.read_text()
    edit(root / "linalg.py", SOURCES["linalg.py"] + "# changed\n")

    def refuse(*args, **kwargs):
        raise PermissionError("read-only")

    with monkeypatch.context() as patch:  # caches that cannot be deleted
        patch.setattr(_kernel_cache.os, "unlink", refuse)
        assert refresh_kernel_cache(package) is False
    with monkeypatch.context() as patch:  # a read-only install
        patch.setattr(_kernel_cache.os, "access", lambda *args: False)
        assert refresh_kernel_cache(package) is False
    assert cached(root) == set(CACHES)
    assert record.read_text() == before  # so the next import tries again
    assert refresh_kernel_cache(package)
    assert cached(root) == set(CACHES) - set(DEPENDS_ON_LINALG)
    assert refresh_kernel_cache([root.parent / "missing"]) is False


REAL_KERNELS = (
    "import numba\n\n@numba.njit(cache=True)\ndef twice(x):\n    return 2 * x\n\n"
    "def make():\n    @numba.njit(cache=True)\n    def inner(x):\n        return x + 1\n"
    "    return inner\n"
)


def compile_real_kernels(root):
    """Import ``root/real.py`` and run its two kernels, which numba caches; return where."""
    from numba.core.caching import CompileResultCacheImpl

    spec = importlib.util.spec_from_file_location("_kernel_cache_real", root / "real.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    try:
        spec.loader.exec_module(module)
        assert module.twice(2) == 4 and module.make()(1) == 2
        # the folder numba itself chose (in the tree, or under NUMBA_CACHE_DIR)
        locator = CompileResultCacheImpl(module.twice.py_func)._locator
        return Path(locator.get_cache_path())
    finally:
        del sys.modules[spec.name]


def check_real_cache_files_are_dropped(root):
    edit(root / "real.py", REAL_KERNELS)
    edit(root / "keep.py", "import numba\n")
    assert refresh_kernel_cache([root])
    cache = compile_real_kernels(root)
    files = sorted(p.name for p in cache.glob("*.nb[ic]"))
    assert any("locals" in name for name in files) and len(files) == 4
    (cache / "keep.f-1.py311.nbi").write_bytes(b"machine code")
    edit(root / "real.py", (root / "real.py").read_text() + "# changed\n")
    assert refresh_kernel_cache([root])
    assert sorted(p.name for p in cache.glob("*.nb[ic]")) == ["keep.f-1.py311.nbi"]
    (cache / "real.twice-3.py311.nbi").write_bytes(b"machine code")
    (root / "__pycache__" / _kernel_cache._RECORD).unlink()  # nothing says what is current
    assert refresh_kernel_cache([root])
    assert not list(cache.glob("*.nb[ic]"))
    return cache


def test_real_numba_cache_files_are_recognised(tmp_path):
    """The names numba gives its cache files, a closure's included, are the ones dropped."""
    check_real_cache_files_are_dropped(tmp_path / "kernels")


def test_the_cache_numba_keeps_under_numba_cache_dir_is_dropped_too(tmp_path):
    """A user's NUMBA_CACHE_DIR moves numba's caches out of the tree: found there too."""
    script = (
        "import sys; from pathlib import Path\n"
        "sys.path.insert(0, sys.argv[1])\n"
        "from test_kernel_cache import check_real_cache_files_are_dropped\n"
        "print(check_real_cache_files_are_dropped(Path(sys.argv[2])))\n"
    )
    user = tmp_path / "user-cache"
    env = {**os.environ, "NUMBA_CACHE_DIR": str(user)}
    done = subprocess.run(
        [sys.executable, "-c", script, str(Path(__file__).parent), str(tmp_path / "kernels")],
        env=env,
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    assert Path(done.stdout.strip()).parent == user  # numba did cache there


def test_a_numba_cache_dir_dropped_for_one_run_is_kept_in_step_by_the_next(tmp_path, monkeypatch):
    """A kernel edited in a run without NUMBA_CACHE_DIR is dropped from it too, and a
    cache folder the record has never seen is emptied before it is trusted."""
    root = tmp_path / "kernels"
    user = tmp_path / "user-cache"
    script = (
        "import sys; from pathlib import Path\n"
        "sys.path.insert(0, sys.argv[1])\n"
        "from test_kernel_cache import check_real_cache_files_are_dropped, compile_real_kernels\n"
        "check_real_cache_files_are_dropped(Path(sys.argv[2]))\n"
        "print(compile_real_kernels(Path(sys.argv[2])))\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", script, str(Path(__file__).parent), str(root)],
        env={**os.environ, "NUMBA_CACHE_DIR": str(user)},
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    cache = Path(done.stdout.strip())
    assert len(list(cache.glob("real.*.nb[ic]"))) == 4
    # this run has no NUMBA_CACHE_DIR: the edit drops the user folder's kernels as well
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    edit(root / "real.py", (root / "real.py").read_text() + "# changed again\n")
    assert refresh_kernel_cache([root])
    assert not list(cache.glob("real.*.nb[ic]"))
    # a folder never seen may hold kernels of any age: all of them go, once
    other = tmp_path / "other-cache"
    stale = Path(str(cache).replace(str(user), str(other))) / "real.twice-3.py311.nbi"
    stale.parent.mkdir(parents=True)
    stale.write_bytes(b"machine code")
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(other))
    assert refresh_kernel_cache([root])
    assert not stale.exists()
    assert not refresh_kernel_cache([root])  # now it is kept in step: nothing to do


def test_a_numba_cache_dir_since_removed_is_forgotten(package, monkeypatch):
    """Else every temporary NUMBA_CACHE_DIR a run was given stays in the record for good."""
    root = package[0]
    gone, kept = root.parent / "gone-cache", root.parent / "kept-cache"
    for folder in (gone, kept):
        folder.mkdir()
        monkeypatch.setenv("NUMBA_CACHE_DIR", str(folder))
        refresh_kernel_cache(package)
    record = root / "__pycache__" / _kernel_cache._RECORD
    assert json.loads(record.read_text())["user_caches"] == sorted([str(gone), str(kept)])
    gone.rmdir()
    monkeypatch.delenv("NUMBA_CACHE_DIR")
    assert not refresh_kernel_cache(package)  # no stamp changed: nothing dropped
    assert json.loads(record.read_text())["user_caches"] == [str(kept)]
    assert cached(root) == set(CACHES)


def test_this_runs_cache_dir_not_yet_created_is_kept_and_the_record_left_alone(
    package, monkeypatch
):
    """numba creates NUMBA_CACHE_DIR only at its first write: until then it stays listed."""
    root = package[0]
    later = root.parent / "created-later"
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(later))
    assert refresh_kernel_cache(package)  # never seen: kept in step from now on
    record = root / "__pycache__" / _kernel_cache._RECORD
    written = record.stat().st_ino
    assert not refresh_kernel_cache(package)
    assert json.loads(record.read_text())["user_caches"] == [str(later)]
    assert record.stat().st_ino == written  # nothing to record: not written again
