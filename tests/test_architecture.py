"""The dependency rule of ARCHITECTURE.md, checked by walking the imports of `penfree/`.

Every ``import`` and ``from ... import`` counts, also inside functions (the import
cycle this test was written against ran through function-level imports). The rules:

- no import cycle between modules;
- the stages of `penfree.core` import only the base modules and the stages listed in
  `STAGE_DEPS`; nothing outside the orchestration's callers imports `penfree.core.pipeline`;
- `penfree.formats` imports no `penfree.core`, `penfree.report` or `penfree.cli`;
- no private name (``_x``) is imported from another stage or package;
- no module-level ``__getattr__`` (re-exports) except the package's lazy public API.
"""

import ast
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "penfree"

#: Stage -> the stages it may import (besides the base modules of penfree.core).
STAGE_DEPS = {
    "fit": set(),
    "contact": set(),
    "verify": {"fit", "contact"},
    "trust": {"contact"},
}
#: Packages that may import the orchestration (penfree.core.pipeline).
ORCHESTRATION_CALLERS = ("penfree.core.pipeline", "penfree.report", "penfree.scaleout", "penfree.cli")


def _module_names():
    mods = {}
    for path in sorted(PKG.rglob("*.py")):
        parts = list(path.relative_to(PKG.parent).with_suffix("").parts)
        is_pkg = parts[-1] == "__init__"
        if is_pkg:
            parts = parts[:-1]
        mods[".".join(parts)] = (path, is_pkg)
    return mods


MODULES = _module_names()


def imports_of(name, path, is_pkg, known):
    """``[(target module, imported name or None, line)]`` of every import in one module."""
    package = name if is_pkg else name.rpartition(".")[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [(a.name, None, node.lineno) for a in node.names if a.name.split(".")[0] == "penfree"]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                src = ".".join(base + ([node.module] if node.module else []))
            else:
                src = node.module or ""
            if src.split(".")[0] != "penfree":
                continue
            for a in node.names:
                sub = f"{src}.{a.name}"
                out.append((sub, None, node.lineno) if sub in known else (src, a.name, node.lineno))
    return out


def build_graph(modules):
    return {name: imports_of(name, path, is_pkg, modules) for name, (path, is_pkg) in modules.items()}


GRAPH = build_graph(MODULES)


def find_cycle(edges):
    """One import cycle as a list of modules (first == last), or None. `edges`: name -> targets."""
    WHITE, GREY, BLACK = 0, 1, 2
    colour = dict.fromkeys(edges, WHITE)
    for root in edges:
        if colour[root] != WHITE:
            continue
        stack = [(root, iter(edges[root]))]
        colour[root] = GREY
        while stack:
            node, it = stack[-1]
            nxt = next(it, None)
            if nxt is None:
                colour[node] = BLACK
                stack.pop()
            elif colour.get(nxt, BLACK) == GREY:
                path = [n for n, _ in stack]
                return path[path.index(nxt):] + [nxt]
            elif colour.get(nxt, BLACK) == WHITE:
                colour[nxt] = GREY
                stack.append((nxt, iter(edges[nxt])))
    return None


def _stage(mod):
    parts = mod.split(".")
    if len(parts) >= 3 and parts[:2] == ["penfree", "core"] and parts[2] in STAGE_DEPS:
        return parts[2]
    return None


def _unit(mod):
    """The stage or package a module belongs to (private names stay inside it)."""
    parts = mod.split(".")
    if len(parts) >= 3 and parts[:2] == ["penfree", "core"] and (parts[2] in STAGE_DEPS or parts[2] == "pipeline"):
        return ".".join(parts[:3])
    _, is_pkg = MODULES.get(mod, (None, False))
    return mod if is_pkg else mod.rpartition(".")[0]


def _within(mod, prefix):
    return mod == prefix or mod.startswith(prefix + ".")


def test_cycle_finder_finds_a_planted_cycle():
    assert find_cycle({"a": ["b"], "b": ["c"], "c": ["a"], "d": ["a"]}) in (
        ["a", "b", "c", "a"], ["b", "c", "a", "b"], ["c", "a", "b", "c"])
    assert find_cycle({"a": ["b"], "b": [], "c": ["a", "b"]}) is None


def test_the_walk_sees_function_level_and_relative_imports():
    # penfree.core.pipeline.deform imports the verify stage inside start_state_intersections.
    targets = {t for t, _, _ in GRAPH["penfree.core.pipeline.deform"]}
    assert "penfree.core.verify.pairs" in targets and "penfree.core.fit.step" in targets


def test_no_import_cycle():
    edges = {m: sorted({t for t, _, _ in deps if t in MODULES and t != m}) for m, deps in GRAPH.items()}
    cycle = find_cycle(edges)
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_stages_import_only_base_modules_and_earlier_stages():
    bad = []
    for mod, deps in GRAPH.items():
        if not _within(mod, "penfree.core") or _within(mod, "penfree.core.pipeline"):
            continue
        own = _stage(mod)
        allowed = STAGE_DEPS[own] | {own} if own else set()
        for target, _, line in deps:
            if not _within(target, "penfree.core"):
                if _within(target, "penfree.report") or _within(target, "penfree.cli") \
                        or _within(target, "penfree.formats"):
                    bad.append(f"{mod}:{line} imports {target}")
                continue
            if _within(target, "penfree.core.pipeline"):
                bad.append(f"{mod}:{line} imports the orchestration {target}")
            elif (st := _stage(target)) is not None and st not in allowed:
                bad.append(f"{mod}:{line} ({own or 'base'}) imports stage {st} ({target})")
    assert not bad, "\n".join(bad)


def test_only_the_callers_import_the_orchestration():
    bad = [f"{mod}:{line} imports {target}" for mod, deps in GRAPH.items() for target, _, line in deps
           if _within(target, "penfree.core.pipeline")
           and not any(_within(mod, caller) for caller in ORCHESTRATION_CALLERS)]
    assert not bad, "\n".join(bad)


def test_formats_stay_below_the_library():
    bad = [f"{mod}:{line} imports {target}" for mod, deps in GRAPH.items() if _within(mod, "penfree.formats")
           for target, _, line in deps
           if any(_within(target, p) for p in ("penfree.core", "penfree.report", "penfree.cli"))]
    assert not bad, "\n".join(bad)


def test_no_private_name_crosses_a_stage():
    bad = []
    for mod, deps in GRAPH.items():
        for target, name, line in deps:
            if name and name.startswith("_") and not name.startswith("__") and _unit(target) != _unit(mod):
                bad.append(f"{mod}:{line} imports private {name} from {target}")
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize("mod", sorted(MODULES))
def test_no_module_getattr_reexports(mod):
    path, _ = MODULES[mod]
    if mod == "penfree":
        return  # the lazy public API (keeps `import penfree` cheap)
    tree = ast.parse(path.read_text())
    names = {n.name for n in tree.body if isinstance(n, ast.FunctionDef)}
    assert "__getattr__" not in names, f"{mod} defines a module-level __getattr__"
