"""The package's import rules: the library never imports the simulators, benchmarks or CLI;
no cycle between its packages; at most six modules at the top level.

Every import counts, also those under ``if TYPE_CHECKING:`` and inside functions: a rule
that a lazy import may break holds nothing.
"""

from __future__ import annotations

import ast
import shutil
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "camwhisker"
#: Above the library: they may import it; it imports none of them.
OUTER = ("sim", "bench", "cli")
MAX_TOP_MODULES = 6


def _unit(parts: tuple[str, ...]) -> str | None:
    """The top-level unit (package or module) of a dotted camwhisker name."""
    return parts[1] if len(parts) > 1 and parts[0] == "camwhisker" else None


def package_imports(root: Path) -> dict[str, set[tuple[str, str]]]:
    """Top-level unit -> {(imported unit, 'file:line')} over every .py file under ``root``."""
    edges: dict[str, set[tuple[str, str]]] = {}
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root.parent).with_suffix("").parts
        me = _unit(rel)
        if me is None or me in ("__init__", "__main__"):
            continue
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    base = rel[: len(rel) - node.level] + tuple((node.module or "").split("."))
                else:
                    base = tuple((node.module or "").split("."))
                # `from camwhisker import sim` names the unit in the alias.
                names = [base + (a.name,) if len(base) == 1 else base for a in node.names]
            elif isinstance(node, ast.Import):
                names = [tuple(a.name.split(".")) for a in node.names]
            else:
                continue
            for name in names:
                unit = _unit(name)
                if unit and unit != me:
                    where = f"{path.relative_to(root.parent)}:{node.lineno}"
                    edges.setdefault(me, set()).add((unit, where))
    return edges


def outer_imports(root: Path) -> list[str]:
    """Library imports of the simulators, benchmarks or CLI, as 'file:line -> unit'."""
    edges = package_imports(root)
    return sorted(f"{where} -> {unit}" for me, targets in edges.items() if me not in OUTER
                  for unit, where in targets if unit in OUTER)


def cycles(root: Path) -> list[list[str]]:
    """Strongly connected groups of more than one top-level unit (Tarjan)."""
    graph = {me: {u for u, _ in t} for me, t in package_imports(root).items()}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                found.append(sorted(group))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def top_modules(root: Path) -> list[str]:
    return sorted(p.name for p in root.glob("*.py") if p.name not in ("__init__.py", "__main__.py"))


def test_library_never_imports_the_simulators_benchmarks_or_cli():
    assert outer_imports(PACKAGE) == []


def test_no_cycle_between_packages():
    assert cycles(PACKAGE) == []


def test_top_level_holds_at_most_six_modules():
    assert len(top_modules(PACKAGE)) <= MAX_TOP_MODULES, top_modules(PACKAGE)


def test_simulators_live_under_sim():
    assert (PACKAGE / "sim" / "mechanics").is_dir() and (PACKAGE / "sim" / "render").is_dir()
    assert not (PACKAGE / "mechanics").exists() and not (PACKAGE / "synth").exists()


@pytest.fixture(scope="module")
def planted(tmp_path_factory) -> Path:
    """A copy of the package to plant bad imports in."""
    root = tmp_path_factory.mktemp("planted") / "camwhisker"
    shutil.copytree(PACKAGE, root, ignore=shutil.ignore_patterns("__pycache__", "*.html"))
    return root


@pytest.mark.parametrize("line", [
    "from camwhisker.sim.mechanics import WhiskerMechanics",
    "    from camwhisker.bench import chain",  # a lazy import, inside a function
    "from camwhisker import cli",
    "import camwhisker.sim.render.render",
])
def test_a_planted_outer_import_is_found(planted, line):
    target = planted / "contact" / "gm.py"
    original = target.read_text()
    body = f"def _planted():\n{line}\n" if line.startswith(" ") else line + "\n"
    target.write_text(original + "\n" + body)
    try:
        found = outer_imports(planted)
    finally:
        target.write_text(original)
    # Exactly the planted line: one finding, in contact/gm.py, naming the unit.
    assert len(found) == 1, found
    assert found[0].startswith("camwhisker/contact/gm.py:")
    assert found[0].split(" -> ")[1] in OUTER


def test_a_planted_cycle_is_found(planted):
    # files/ sits at the bottom; an import of contact/ from it closes a loop.
    target = planted / "files" / "tables.py"
    original = target.read_text()
    target.write_text(original + "\nfrom camwhisker.contact.gm import r_gm  # noqa\n")
    try:
        found = cycles(planted)
    finally:
        target.write_text(original)
    assert found and any({"files", "contact"} <= set(group) for group in found), found


def test_a_seventh_top_level_module_is_counted(planted):
    for k in range(MAX_TOP_MODULES + 1 - len(top_modules(planted))):
        (planted / f"planted_{k}.py").write_text("")
    try:
        assert len(top_modules(planted)) == MAX_TOP_MODULES + 1
    finally:
        for p in planted.glob("planted_*.py"):
            p.unlink()


def test_importing_the_plots_leaves_the_callers_backend_alone():
    # A notebook's backend must survive `import camwhisker.contact.plots` and a saved figure.
    import subprocess
    import sys

    code = ("import matplotlib; matplotlib.use('svg'); "
            "import camwhisker.contact.plots, camwhisker.calibration.validate, "
            "camwhisker.calibration.report; print(matplotlib.get_backend())")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)  # fmt: skip
    assert out.stdout.strip() == "svg"
