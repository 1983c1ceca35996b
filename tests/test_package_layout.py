"""No package attribute hides a submodule of the same name.

``drafttwin.mechanics.simulate`` was the function while ``mechanics/simulate.py`` existed, so a
dotted path such as ``drafttwin.mechanics.simulate.reference_node_rpm`` in a docstring or a
``mock.patch`` target resolved to the function and raised ``AttributeError``. The modules carry
their own names (``mechanics/simulation.py``, ``sliver/irregularity.py``, ...), so every
``package.name`` whose ``name.py`` exists is that module.
"""

from __future__ import annotations

import importlib
import pkgutil
import types

import drafttwin


def _packages() -> list[types.ModuleType]:
    names = [
        info.name for info in pkgutil.walk_packages(drafttwin.__path__, "drafttwin.") if info.ispkg
    ]
    return [drafttwin, *(importlib.import_module(name) for name in names)]


def test_no_attribute_shadows_its_submodule() -> None:
    shadowed = []
    for package in _packages():
        for info in pkgutil.iter_modules(package.__path__):
            value = getattr(package, info.name, None)
            if value is not None and not isinstance(value, types.ModuleType):
                shadowed.append(f"{package.__name__}.{info.name} is a {type(value).__name__}")
    assert not shadowed, "attributes hiding their submodules: " + "; ".join(shadowed)


def test_documented_reference_integrator_resolves() -> None:
    from drafttwin.mechanics.simulation import reference_node_rpm

    module = importlib.import_module("drafttwin.mechanics.simulation")
    assert drafttwin.mechanics.simulation is module
    assert module.reference_node_rpm is reference_node_rpm
