"""The package's import structure: no module uses another module's private names, no import cycles, and no
import from a folder to one above it (docs/architecture.md, *Package layout*).

Every ``import`` and ``from ... import`` of the package is read with :mod:`ast`, wherever it stands
(module level or inside a function: a cycle held off by a local import is still a cycle).
"""

from __future__ import annotations

import ast
import pathlib

import facestats

ROOT = pathlib.Path(facestats.__file__).resolve().parent


def _modules():
    """``{module name: path}`` of every module of the package."""
    out = {}
    for path in sorted(ROOT.rglob("*.py")):
        parts = list(path.relative_to(ROOT.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


MODULES = _modules()


def _resolve(module, node):
    """The absolute module name of an ``ImportFrom`` node inside ``module``."""
    if node.level == 0:
        return node.module
    is_pkg = MODULES[module].name == "__init__.py"
    base = module.split(".")
    base = base if is_pkg else base[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _imports(module):
    """``[(imported module, name or None, line)]`` and the local aliases bound to package modules."""
    tree = ast.parse(MODULES[module].read_text(), str(MODULES[module]))
    found, aliases = [], {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split(".")[0] == "facestats":
                    found.append((a.name, None, node.lineno))
                    if a.asname:
                        aliases[a.asname] = a.name
        elif isinstance(node, ast.ImportFrom):
            target = _resolve(module, node)
            if not target or target.split(".")[0] != "facestats":
                continue
            for a in node.names:
                sub = f"{target}.{a.name}"
                if sub in MODULES:  # a submodule
                    found.append((sub, None, node.lineno))
                    aliases[a.asname or a.name] = sub
                else:
                    found.append((target, a.name, node.lineno))
    return tree, found, aliases


def _private(name):
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def test_no_module_imports_another_modules_private_names():
    bad = []
    for module in MODULES:
        tree, found, aliases = _imports(module)
        for target, name, line in found:
            if target != module and ((name and _private(name)) or any(_private(p) for p in target.split(".")[1:])):
                bad.append(f"{module}:{line} imports {target}{'.' + name if name else ''}")
        for node in ast.walk(tree):  # module._name through an alias of another package module
            if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in aliases:
                if aliases[node.value.id] != module and _private(node.attr):
                    bad.append(f"{module}:{node.lineno} uses {aliases[node.value.id]}.{node.attr}")
    assert not bad, "private names used across modules:\n" + "\n".join(bad)


def test_no_import_cycles():
    graph = {m: sorted({t for t, _, _ in _imports(m)[1] if t in MODULES and t != m}) for m in MODULES}
    cycles, state, stack = [], {}, []

    def visit(m):  # depth-first search; a grey node met again closes a cycle
        state[m] = "grey"
        stack.append(m)
        for t in graph[m]:
            if state.get(t) == "grey":
                cycles.append(stack[stack.index(t) :] + [t])
            elif t not in state:
                visit(t)
        stack.pop()
        state[m] = "black"

    for m in sorted(graph):
        if m not in state:
            visit(m)
    assert not cycles, "import cycles:\n" + "\n".join(" -> ".join(c) for c in cycles)


#: The floors of docs/architecture.md, from the ground up: a folder may import its own floor's modules and those of
#: the floors below, never a folder above, nor another folder of its own floor unless :data:`SIDEWAYS` lists the pair.
FLOORS = {
    "errors": 0,
    "core": 1,
    "model": 2,
    "face": 2,
    "io": 3,
    "acquire": 4,
    "pipeline": 5,
    "relight": 5,
    "analysis": 5,
    "edit": 6,
    "web": 6,
    "cli": 7,
    "__main__": 8,
}
#: Imports between folders of one floor that docs/architecture.md names: edit/ takes the region samples of
#: analysis.population, web/ the region statistics of analysis.
SIDEWAYS = {("edit", "analysis"), ("web", "analysis")}


def _folder(module):
    """The folder (or top-level module) of ``facestats.<folder>...``; None for the package itself."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else None


def test_no_folder_imports_a_folder_above_it():
    assert {_folder(m) for m in MODULES} - {None} == set(FLOORS), "a folder without a floor: add it to FLOORS"
    bad = []
    for module in MODULES:
        here = _folder(module)
        for target, name, line in _imports(module)[1]:
            there = _folder(target)
            if here is None or there is None or here == there:
                continue
            if FLOORS[there] > FLOORS[here] or (FLOORS[there] == FLOORS[here] and (here, there) not in SIDEWAYS):
                bad.append(f"{module}:{line} imports {target} ({there}/ is not below {here}/)")
    assert not bad, "imports that run up the floors:\n" + "\n".join(bad)


def test_the_walk_sees_the_package():
    # The checks above would pass vacuously on an empty walk.
    assert {"facestats.model.dipole", "facestats.io.store", "facestats.cli"} <= set(MODULES)
    _, found, _ = _imports("facestats.model.skin")
    assert any(t == "facestats.model.dipole" for t, _, _ in found)
