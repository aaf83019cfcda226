"""Every module's docstring examples run and pass (``make test`` runs them through this test)."""

import doctest
import importlib
import pkgutil

import pytest

# gonio.sim and gonio.drivers live in their own top-level folders (pyproject maps them into gonio), so
# an editable install does not show them under gonio's own path: walk each root.
ROOTS = ("gonio", "gonio.sim", "gonio.drivers")


def _modules() -> list[str]:
    names = set(ROOTS)
    for root in ROOTS:
        package = importlib.import_module(root)
        for info in pkgutil.walk_packages(package.__path__, prefix=f"{root}."):
            names.add(info.name)
    return sorted(names)


MODULES = _modules()


def test_every_package_is_walked():
    for part in ("gonio.sim.materials", "gonio.drivers", "gonio.kinematics", "gonio.motion", "gonio.plan"):
        assert any(m.startswith(part) for m in MODULES), part


@pytest.mark.parametrize("name", MODULES)
def test_module_doctests(name):
    module = importlib.import_module(name)
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE,
                             verbose=False, report=False)
    assert result.failed == 0, f"{name}: {result.failed} of {result.attempted} examples failed"
