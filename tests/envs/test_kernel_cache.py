"""The package's numba caches are dropped when a kernel source changes, kept otherwise."""

import os

from manualcontrol.envs._kernel_cache import refresh_kernel_cache, source_stamp


def make_package(root):
    (root / "kernels").mkdir(parents=True)
    (root / "kernels" / "algebra.py").write_text("import numba\n\n@numba.njit\ndef step(): pass\n")
    (root / "kernels" / "cli.py").write_text("print('no kernels here, numba is only named')\n")
    cache = root / "kernels" / "__pycache__"
    cache.mkdir()
    for name in ("algebra.step-10.py311.nbi", "algebra.step-10.py311.1.nbc"):
        (cache / name).write_bytes(b"machine code")
    return [root / "kernels"], cache


def test_a_changed_kernel_source_drops_the_cached_kernels(tmp_path):
    roots, cache = make_package(tmp_path)
    assert refresh_kernel_cache(roots)  # no stamp yet: a fresh clone
    (cache / "algebra.step-10.py311.nbi").write_bytes(b"compiled again")
    assert not refresh_kernel_cache(roots)  # nothing changed: caches kept
    assert (cache / "algebra.step-10.py311.nbi").is_file()
    # editing a file without kernels keeps them too
    (roots[0] / "cli.py").write_text("print('numba is named, no kernels')  # longer\n")
    assert not refresh_kernel_cache(roots)
    # editing a kernel source drops every cached kernel of the package
    before = source_stamp(roots)
    source = roots[0] / "algebra.py"
    source.write_text("from numba import njit\n\n@njit\ndef step(): return 1  # changed\n")
    os.utime(source, ns=(1, 2))
    assert source_stamp(roots) != before
    assert refresh_kernel_cache(roots)
    assert not list(cache.glob("*.nb[ic]"))
    # a kernel built another way counts too: numba imported under another name
    before = source_stamp(roots)
    (roots[0] / "ufuncs.py").write_text(
        "import numba as nb\n\nsquare = nb.vectorize(lambda x: x * x)\n"
    )
    assert source_stamp(roots) != before


def test_a_place_that_cannot_hold_a_stamp_leaves_the_caches_alone(tmp_path):
    assert refresh_kernel_cache([tmp_path / "missing"]) is False
