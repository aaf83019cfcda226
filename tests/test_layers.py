"""The house keeps its shape: no module reaches into another's private names, no import goes up a layer,
and no two modules import each other (directly or round a circle), lazy imports inside functions
included. Read from the source with ``ast``; nothing is imported.

Layers, lowest first (a module may import its own layer and those below):

0. foundations: conventions and shared types (geometry, clock, protocols, the registries, the Dr.Jit
   backend), and the formats' byte layouts;
1. hardware and physics: the config models (each device's, owned by its driver), drivers (talk bytes to
   devices) and the simulated devices' physics (materials, optics, frames, colour);
2. geometry of motion: kinematics, motion, plans;
3. data: the journal, calibration, the dataset, the measured BRDF, exports, plots, fits, the report,
   adaptive sampling (where the next poses go, from the samples so far);
4. machinery: the gantry as assembled, the engine that runs campaigns (and its unit sources: fly
   scanning's, adaptive rounds'), fly scanning, simulated
   gantries and the emulators that stand in for devices;
5. the campaign floor: campaigns and their lifecycle;
6. faces: the daemon, the CLI, and batch runs on Dask.
"""

from __future__ import annotations

import ast
from collections import defaultdict
from functools import cache
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = {"gonio": ROOT / "gonio", "gonio.drivers": ROOT / "drivers", "gonio.sim": ROOT / "sim"}


def _modules() -> dict[str, Path]:
    out = {}
    for prefix, folder in PACKAGES.items():
        for path in sorted(folder.rglob("*.py")):
            rel = path.relative_to(folder).with_suffix("")
            parts = [p for p in rel.parts if p != "__init__"]
            out[".".join([prefix, *parts])] = path
    return out


MODULES = _modules()


def _resolve(name: str) -> str | None:
    """The project module an imported name lives in (the longest module prefix), or None."""
    parts = name.split(".")
    for k in range(len(parts), 0, -1):
        cand = ".".join(parts[:k])
        if cand in MODULES:
            return cand
    return None


def _imports(module: str, tree: ast.AST) -> list[tuple[str, str, int]]:
    """(imported module, name or '', line) of every import of a project module in ``tree``."""
    package = module if MODULES[module].name == "__init__.py" else module.rsplit(".", 1)[0]
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                target = _resolve(a.name)
                if target:
                    out.append((target, "", node.lineno))
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")
                anchor = anchor[: len(anchor) - (node.level - 1)]
                base = ".".join([*anchor, *([base] if base else [])])
            for a in node.names:
                sub = _resolve(f"{base}.{a.name}")
                if sub and sub != _resolve(base):   # `from pkg import module`
                    out.append((sub, "", node.lineno))
                else:
                    target = _resolve(base)
                    if target:
                        out.append((target, a.name, node.lineno))
    return out


@cache
def _trees() -> dict[str, ast.AST]:
    """Every module's syntax tree, parsed once and only by the tests that read them (not at collection,
    which every test process pays)."""
    return {m: ast.parse(p.read_text(), filename=str(p)) for m, p in MODULES.items()}


def _private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _defined_private_attributes(tree: ast.AST) -> set[str]:
    """Private attribute names a module defines itself: methods, class attributes and ``x._name = ...``
    assignments anywhere in it."""
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) and _private(node.name):
            out.add(node.name)
        elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store) and _private(node.attr):
            out.add(node.attr)
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            out.update(t.id for t in targets if isinstance(t, ast.Name) and _private(t.id))
    return out


def test_no_module_uses_another_modules_private_names():
    found = []
    for module, tree in _trees().items():
        where = MODULES[module].relative_to(ROOT)
        own = _defined_private_attributes(tree)
        for target, name, line in _imports(module, tree):
            if name and _private(name) and target != module:
                found.append(f"{where}:{line}: imports {name} from {target}")
        for node in ast.walk(tree):
            if not (isinstance(node, ast.Attribute) and _private(node.attr)):
                continue
            if isinstance(node.value, ast.Name) and node.value.id in ("self", "cls"):
                continue
            if isinstance(node.value, ast.Call) and getattr(node.value.func, "id", None) == "super":
                continue
            if node.attr not in own:
                found.append(f"{where}:{node.lineno}: uses .{node.attr}, which {module} does not define")
    assert not found, "\n".join(found)


#: module prefix -> layer (the longest prefix that matches decides).
LAYERS = {
    "gonio": 0, "gonio.geometry": 0, "gonio.clock": 0, "gonio.protocols": 0, "gonio.registry": 0,
    "gonio.registries": 0, "gonio.jit": 0, "gonio.formats": 0, "gonio.configs": 0, "gonio.files": 0,
    "gonio.config": 1, "gonio.device_config": 1,
    "gonio.drivers": 1, "gonio.sim.materials": 1, "gonio.sim.light": 1, "gonio.colour": 1, "gonio.frames": 1,
    "gonio.kinematics": 2, "gonio.motion": 2, "gonio.plan": 2,
    "gonio.store": 3, "gonio.calibrate": 3, "gonio.dataset": 3, "gonio.brdf": 3, "gonio.interpolate": 3,
    "gonio.export": 3, "gonio.plot": 3, "gonio.slices": 3, "gonio.fit": 3, "gonio.report": 3,
    "gonio.adaptive": 3, "gonio.adaptive.units": 4,
    "gonio.gantry": 4, "gonio.wiring": 4, "gonio.runner": 4, "gonio.executor": 4, "gonio.units": 4,
    "gonio.manual": 4, "gonio.reference": 4, "gonio.fly": 4, "gonio.sim": 4,
    "gonio.campaign": 5, "gonio.lifecycle": 5,
    "gonio.daemon": 6, "gonio.cli": 6, "gonio.batch": 6,
}


def _layer(module: str) -> int:
    parts = module.split(".")
    for k in range(len(parts), 0, -1):
        key = ".".join(parts[:k])
        if key in LAYERS:
            return LAYERS[key]
    raise AssertionError(f"{module}: no layer (add it to LAYERS)")


def test_no_import_goes_up_a_layer():
    found = []
    for module, tree in _trees().items():
        for target, _, line in _imports(module, tree):
            if _layer(target) > _layer(module):
                found.append(f"{MODULES[module].relative_to(ROOT)}:{line}: {module} (layer {_layer(module)}) "
                             f"imports {target} (layer {_layer(target)})")
    assert not found, "\n".join(found)


def test_no_import_cycle():
    graph = defaultdict(set)
    for module, tree in _trees().items():
        for target, _, _ in _imports(module, tree):
            # A package's __init__ gathering its own modules, and a module importing its package's
            # names, are one unit: only edges between different units count.
            if target != module and not (target.startswith(module + ".") or module.startswith(target + ".")):
                graph[module].add(target)
    # Tarjan's strongly connected components.
    index, low, stack, on, sccs, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                sccs.append(sorted(comp))

    for v in sorted(MODULES):
        if v not in index:
            visit(v)
    assert not sccs, "\n".join(" <-> ".join(c) for c in sccs)


def test_every_module_has_a_layer():
    for module in MODULES:
        _layer(module)
