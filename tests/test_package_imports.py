"""Package imports: every public name as before, none imported before it is used.

The package ``__init__`` files export their names lazily (PEP 562,
``manualcontrol.envs._lazy``): ``from manualcontrol.estimators import DEKF`` must give
the very object its module defines, ``__all__`` and ``dir()`` must list what they
listed, and the ``if TYPE_CHECKING`` imports that tools read must say the same as the
table Python reads. The start-up checks run in fresh processes.
"""

import ast
import importlib
import inspect
import subprocess
import sys
import textwrap

import pytest

LAZY_PACKAGES = (
    "manualcontrol.pilots",
    "manualcontrol.estimators",
    "manualcontrol.estimators.filters",
    "manualcontrol.agents",
)
ENV_IDS = (
    "ManualControl/CompensatoryTracking-v0",
    "ManualControl/PursuitTracking-v0",
    "ManualControl/PreviewTracking-v0",
    "ManualControl/PostviewTracking-v0",
    "ManualControl/LaneKeeping-v0",
)


def declared(package):
    """{name: module} as the package's ``if TYPE_CHECKING:`` imports declare them."""
    tree = ast.parse(inspect.getsource(importlib.import_module(package)))
    blocks = [
        node
        for node in tree.body
        if isinstance(node, ast.If) and ast.unparse(node.test) == "TYPE_CHECKING"
    ]
    assert len(blocks) == 1, f"{package}: one `if TYPE_CHECKING:` block of imports"
    names = {}
    for node in blocks[0].body:
        assert isinstance(node, ast.ImportFrom), ast.unparse(node)
        for alias in node.names:
            assert alias.asname is None, ast.unparse(node)
            names[alias.name] = node.module
    return names


def fresh(code):
    """Run ``code`` in a new interpreter; its stdout."""
    result = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True
    )
    assert result.returncode == 0, result.stderr
    return result.stdout


@pytest.mark.parametrize("package", LAZY_PACKAGES)
def test_every_public_name_is_the_object_its_module_defines(package):
    module = importlib.import_module(package)
    homes = declared(package)
    assert sorted(module.__all__) == sorted(homes)
    assert len(set(module.__all__)) == len(module.__all__)
    for name, home in homes.items():
        expected = getattr(importlib.import_module(home), name)
        assert getattr(module, name) is expected, f"{package}.{name}"
        namespace = {}
        exec(f"from {package} import {name}", namespace)
        assert namespace[name] is expected
    namespace = {}
    exec(f"from {package} import *", namespace)
    assert {n for n in namespace if n != "__builtins__"} == set(module.__all__)
    assert set(module.__all__) <= set(dir(module))


@pytest.mark.parametrize("package", LAZY_PACKAGES)
def test_an_unknown_name_is_an_attribute_error(package):
    module = importlib.import_module(package)
    with pytest.raises(AttributeError, match=f"module '{package}' has no attribute 'nothing'"):
        module.nothing  # noqa: B018
    assert not hasattr(module, "nothing")


def test_every_public_name_resolves_in_a_fresh_process():
    # the table Python reads, checked against the modules before anything else is imported
    out = fresh(
        f"""
        import importlib
        for package in {LAZY_PACKAGES!r}:
            module = importlib.import_module(package)
            for name in module.__all__:
                getattr(module, name)
        print("ok")
        """
    )
    assert out.strip() == "ok"


def test_submodules_still_import_through_their_package():
    from manualcontrol.estimators import _pilot_core, registry
    from manualcontrol.estimators.filters import monitor

    assert registry.__name__ == "manualcontrol.estimators.registry"
    assert _pilot_core.__name__ == "manualcontrol.estimators._pilot_core"
    assert monitor.__name__ == "manualcontrol.estimators.filters.monitor"


def test_importing_a_package_imports_none_of_its_members():
    out = fresh(
        """
        import sys
        import manualcontrol.agents, manualcontrol.estimators, manualcontrol.pilots
        heavy = ("numba", "scipy.signal", "scipy.stats", "scipy.optimize", "matplotlib", "torch")
        loaded = sorted(m for m in sys.modules if m.startswith("manualcontrol."))
        print(sorted(m for m in heavy if m in sys.modules))
        print(loaded)
        """
    )
    heavy, loaded = out.splitlines()
    assert heavy == "[]"
    assert "members" not in loaded and "pilots.models" not in loaded and "wrappers" not in loaded


def test_the_command_line_loads_what_each_command_uses():
    out = fresh(
        """
        import contextlib, io, sys
        from manualcontrol.bench.cli import main

        def modules():
            return {m for m in sys.modules if m.split(".")[0] in (
                "numba", "scipy", "torch", "matplotlib", "stable_baselines3", "pygame"
            )} | {m for m in sys.modules if ".members." in m}

        for command in ("", "identify", "bench", "suites", "train", "evaluate"):
            with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):
                main([command, "--help"] if command else ["--help"])
        print(sorted(modules()))
        with contextlib.redirect_stdout(io.StringIO()):
            main(["estimators"])
        print(sorted(modules()))
        with contextlib.redirect_stdout(io.StringIO()):
            main(["suites"])
        print(sorted(modules()), "manualcontrol.bench.scenarios" in sys.modules)
        """
    )
    after_help, after_estimators, after_suites = out.splitlines()
    assert after_help == "[]"
    assert after_estimators == "[]"
    # a listing reads the suite files; it builds no pilot, estimator or environment
    assert after_suites == "[] False"


@pytest.mark.parametrize("first", ["manualcontrol.envs", "manualcontrol.estimators"])
def test_importing_a_package_registers_the_environments(first):
    out = fresh(
        f"""
        import gymnasium
        import {first}
        for env_id in {ENV_IDS!r}:
            env = gymnasium.make(env_id)
            env.reset(seed=0)
            env.close()
        print("ok")
        """
    )
    assert out.strip() == "ok"


def test_an_environment_id_naming_its_module_needs_no_import_first():
    out = fresh(
        """
        import gymnasium
        env = gymnasium.make("manualcontrol.envs:ManualControl/PreviewTracking-v0")
        env.reset(seed=0)
        print(type(env.unwrapped).__name__)
        """
    )
    assert out.strip() == "PreviewTracking"
