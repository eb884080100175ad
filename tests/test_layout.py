"""The package's import graph: no import circle, no upward import.

Every ``import`` / ``from ... import`` of ngcontact (module level and inside functions) is read
from the source.  A module belongs to a *unit* (the first name under ``ngcontact``); a unit may
import only the units listed in :data:`ALLOWED` (the layers of the README's module map), and the
module graph must have no cycle.
"""
import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "ngcontact"

_BASE = {"algebra", "domains", "rates", "marking"}
#: unit -> units it may import (besides itself)
ALLOWED = {
    "algebra": set(),
    "domains": set(),
    "rates": set(),
    "marking": set(),
    "problems": {"domains"},
    "discretizations": {"algebra", "problems", "domains"},
    "newton": {"algebra"},
    "estimators": {"algebra", "discretizations", "problems", "domains"},
    "options": _BASE | {"discretizations", "newton", "estimators"},
    "scenes": {"problems", "domains", "twophase"},
    "drivers": _BASE | {"problems", "discretizations", "newton", "estimators", "options"},
    "timestepping": _BASE | {"problems", "discretizations", "newton", "estimators", "results"},
    "results": {"rates", ""},
    "plotting": {"results", "rates", "domains"},
    "studies": _BASE | {"problems", "discretizations", "newton", "estimators", "options", "scenes", "drivers",
                        "results", "plotting", "cli", "twophase", "timestepping"},
    "cli": _BASE | {"problems", "options", "scenes", "drivers", "results", "plotting", "twophase", "timestepping"},
    "twophase": {"algebra", "newton"},
    "__main__": {"cli"},
    "": {"domains", "problems"},  # the package itself: the names of `from ngcontact import ...`
}


def _module_name(path: Path) -> str:
    parts = ("ngcontact",) + path.relative_to(PACKAGE).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_graph() -> dict:
    """module -> set of ngcontact modules it imports (a ``from pkg import name`` of a submodule counts
    as an import of that submodule)."""
    modules = {_module_name(p): p for p in PACKAGE.rglob("*.py")}
    graph = {}
    for mod, path in modules.items():
        is_pkg = path.name == "__init__.py"
        deps = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                deps |= {a.name for a in node.names if a.name.startswith("ngcontact")}
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = mod.split(".") if is_pkg else mod.split(".")[:-1]
                    base = base[:len(base) - node.level + 1]
                    target = ".".join(base + ([node.module] if node.module else []))
                else:
                    target = node.module or ""
                if not target.startswith("ngcontact"):
                    continue
                subs = {f"{target}.{a.name}" for a in node.names} & set(modules)
                deps |= subs or {target}
        graph[mod] = {d for d in deps if d in modules and d != mod}
    return graph


def _unit(mod: str) -> str:
    parts = mod.split(".")
    return parts[1] if len(parts) > 1 else ""


def _cycles(graph: dict) -> list:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph[v]:
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
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_every_unit_is_placed():
    units = {_unit(m) for m in import_graph()}
    assert units <= set(ALLOWED), f"units without a layer: {sorted(units - set(ALLOWED))}"


def test_no_import_circle():
    assert _cycles(import_graph()) == []


def test_no_upward_import():
    bad = [f"{m} -> {d}" for m, deps in import_graph().items() for d in sorted(deps)
           if _unit(d) != _unit(m) and _unit(d) not in ALLOWED[_unit(m)]]
    assert bad == []


def test_the_checks_see_a_circle_and_an_upward_import():
    """The two checks on a made-up graph: they can fail."""
    graph = {"ngcontact.newton.loop": {"ngcontact.estimators.flux"}, "ngcontact.estimators.flux": {"ngcontact.newton.loop"}}
    assert _cycles(graph) == [["ngcontact.estimators.flux", "ngcontact.newton.loop"]]
    assert "estimators" not in ALLOWED[_unit("ngcontact.newton.loop")]
