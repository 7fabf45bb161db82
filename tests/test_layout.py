"""The package's layout: every import points down the data flow, and no import circle.

config/state/fileio/reporting -> physics -> data -> sim -> models, loss -> training ->
evaluation -> deploy -> control -> autopilot (the product) -> lab (reproduce, studies,
benchmarks) -> cli (docs/design.md): the product imports nothing from the lab. The simulator
is a data source above ``data/``: it writes its datasets with ``data``'s writer and split
policy, and nothing in ``data`` knows it. Read from the source's import statements, so a
function-level import counts as much as a top-level one.
"""

from __future__ import annotations

import ast
from pathlib import Path

import slungload

PACKAGE = Path(slungload.__file__).parent
ORDER = {  # wing -> floor; a module may import its own floor and those below
    "_version": 0, "_lazy": 0, "config": 0, "state": 0, "fileio": 0, "run_config": 0,
    "layout": 0, "frames": 0, "reporting": 0, "workers": 0, "cluster": 0, "vehicle_file": 0,
    "vehicle_constants": 0, "smoothing": 0, "online_interval": 0, "input_lag": 0,
    "physics": 1, "load_state": 1, "constants_estimate": 1,
    "data": 2,
    "sim": 3,
    "models": 4, "loss": 4,
    "training": 5,
    "evaluation": 6,
    "deploy": 7,
    "control": 8,
    "autopilot": 9,
    "lab": 10,
    "cli": 11,
}  # fmt: skip


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports(path: Path) -> set[str]:
    """slungload modules that ``path`` imports (``from . import x`` counts as module x)."""
    name = module_name(path)
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target == "slungload" or target.startswith("slungload."):
                subs = [f"{target}.{a.name}" for a in node.names]
                found |= {s for s in subs if _is_module(s)} or {target}
        elif isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name.startswith("slungload")}
    return found


def _is_module(name: str) -> bool:
    rel = Path(*name.split(".")[1:])
    return (PACKAGE / rel).with_suffix(".py").is_file() or (PACKAGE / rel / "__init__.py").is_file()


def wing(module: str) -> str:
    return module.split(".")[1] if module.count(".") else ""


def graph() -> dict[str, set[str]]:
    return {
        module_name(p): imports(p) for p in PACKAGE.rglob("*.py") if p != PACKAGE / "__init__.py"
    }


def upward_imports(edges: dict[str, set[str]]) -> list[str]:
    """Imports of the package root or of a module on a higher floor."""
    out = []
    for module, targets in sorted(edges.items()):
        for target in sorted(targets):
            if target == "slungload":
                out.append(f"{module} imports the package root (import the module instead)")
            elif ORDER[wing(target)] > ORDER[wing(module)]:
                out.append(f"{module} -> {target}")
    return out


def find_circle(edges: dict[str, set[str]]) -> list[str] | None:
    """One import circle (a path that comes back to its start), or None."""
    state: dict[str, int] = {}  # 1 on the current path, 2 done

    def visit(node: str, path: list[str]) -> list[str] | None:
        state[node] = 1
        for nxt in sorted(edges.get(node, ())):
            if state.get(nxt) == 1:
                return [*path, node, nxt]
            if nxt not in state and (found := visit(nxt, [*path, node])):
                return found
        state[node] = 2
        return None

    for node in sorted(edges):
        if node not in state and (found := visit(node, [])):
            return found
    return None


def test_every_import_points_down_the_data_flow():
    assert upward_imports(graph()) == []


def test_every_wing_has_a_floor():
    assert {wing(m) for m in graph()} <= set(ORDER)


def test_no_import_circle():
    assert find_circle(graph()) is None


def test_the_checks_find_an_upward_import_and_a_circle():
    # The two rules must be able to fail: made-up graphs with the faults the package once had.
    bad = {
        "slungload.evaluation.evaluation": {"slungload.evaluation.report", "slungload.deploy.x"},
        "slungload.evaluation.report": {"slungload.evaluation.evaluation"},
    }
    assert upward_imports(bad) == ["slungload.evaluation.evaluation -> slungload.deploy.x"]
    assert find_circle(bad) == [
        "slungload.evaluation.evaluation",
        "slungload.evaluation.report",
        "slungload.evaluation.evaluation",
    ]
    # And the reader sees this package's real imports, relative ones included.
    assert "slungload.evaluation.results" in imports(PACKAGE / "deploy" / "timing.py")


def test_the_simulator_is_a_data_source_above_data():
    # data/ owns datasets (writer, split policy, readers); the simulator writes through them.
    assert ORDER["sim"] > ORDER["data"]
    edges = graph()
    assert "slungload.data.writer" in edges["slungload.sim.dataset"]
    assert not [(m, t) for m, ts in edges.items() if wing(m) == "data" for t in ts
                if wing(t) == "sim"]  # fmt: skip
    assert upward_imports({"slungload.data.importing": {"slungload.sim.dataset"}}) == [
        "slungload.data.importing -> slungload.sim.dataset"
    ]


def test_the_product_imports_nothing_from_the_lab():
    edges = graph()
    product = [m for m in edges if wing(m) not in ("lab", "cli")]
    assert len(product) > 50 and any(wing(m) == "lab" for m in edges)
    assert [(m, t) for m in product for t in edges[m] if wing(t) == "lab"] == []
    # The root's lazy names are the product's too (the root is left out of ``graph``).
    from slungload import _EXPORTS

    assert [m for m in _EXPORTS if m.split(".")[0] == "lab"] == []
    assert upward_imports({"slungload.control.mpc": {"slungload.lab.control.oracle"}}) == [
        "slungload.control.mpc -> slungload.lab.control.oracle"
    ]


def test_importing_every_product_module_loads_nothing_of_the_lab():
    # The import statements say so (above); this checks what a user's process really loads,
    # lazy re-exports and function-level imports run included.
    import subprocess
    import sys

    product = sorted(m for m in graph() if wing(m) not in ("lab", "cli") and "__main__" not in m)
    code = (
        "import importlib, sys\n"
        f"for name in {product!r}:\n"
        "    importlib.import_module(name)\n"
        "import slungload\n"
        "for name in slungload.__all__:\n"
        "    getattr(slungload, name)\n"
        "print(sorted(m for m in sys.modules if m.startswith('slungload.lab')))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "[]"
