"""The dependency graph the architecture promises (docs/architecture.md; issue 14).

Read from the source with :mod:`ast`: every ``import`` of the package, at module level or inside
a function, ``TYPE_CHECKING`` blocks included (a type-only import still points the wrong way).
"""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import breadth_first_order, connected_components

SRC = Path(__file__).resolve().parents[1] / "src" / "starnav"


def _unit(path: Path) -> str:
    """Subpackage or top-level module a file belongs to (``renderer``, ``camera``, ...)."""
    rel = path.relative_to(SRC)
    return rel.parts[0].removesuffix(".py") if len(rel.parts) > 1 else rel.stem


def _imports() -> dict[str, set[tuple[str, str]]]:
    """unit -> {(imported module, importing file)}."""
    out: dict[str, set[tuple[str, str]]] = defaultdict(set)
    for f in SRC.rglob("*.py"):
        tree = ast.parse(f.read_text(), str(f))
        pkg = f.relative_to(SRC.parent).with_suffix("").parts
        pkg = pkg[:-1] if f.name != "__init__.py" else pkg[:-1]
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = list(f.relative_to(SRC.parent).with_suffix("").parts[:-node.level])
                    names = [".".join(base + ([node.module] if node.module else []))]
                else:
                    names = [node.module or ""]
            else:
                continue
            for n in names:
                out[_unit(f)].add((n, str(f.relative_to(SRC))))
    return out


IMPORTS = _imports()


class Graph:
    """Directed graph of units (subpackages and top-level modules) -> units they import."""

    def __init__(self, edges: set[tuple[str, str]], nodes: set[str]) -> None:
        self.edges = set(edges)
        self.nodes = sorted(nodes | {u for e in edges for u in e})

    def has_edge(self, a: str, b: str) -> bool:
        return (a, b) in self.edges

    def _matrix(self) -> csr_matrix:
        ix = {n: i for i, n in enumerate(self.nodes)}
        rows = [ix[a] for a, _ in self.edges]
        cols = [ix[b] for _, b in self.edges]
        n = len(self.nodes)
        return csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))

    def cycles(self) -> list[list[str]]:
        """Strongly connected components of more than one unit."""
        _, labels = connected_components(self._matrix(), directed=True, connection="strong")
        groups: dict[int, list[str]] = defaultdict(list)
        for n, lab in zip(self.nodes, labels, strict=True):
            groups[int(lab)].append(n)
        return sorted(g for g in groups.values() if len(g) > 1)

    def descendants(self, node: str) -> set[str]:
        order = breadth_first_order(self._matrix(), self.nodes.index(node), directed=True,
                                    return_predecessors=False)
        return {self.nodes[i] for i in order} - {node}


def _graph() -> Graph:
    edges = set()
    for unit, mods in IMPORTS.items():
        for m, _ in mods:
            parts = m.split(".")
            if parts[0] == "starnav" and len(parts) > 1 and parts[1] != unit:
                edges.add((unit, parts[1]))
    return Graph(edges, set(IMPORTS))


def test_no_cycles_between_subpackages():
    cycles = _graph().cycles()
    assert not cycles, f"import cycles between subpackages: {cycles}"


def test_nothing_below_config_imports_it():
    g = _graph()
    below = g.descendants("config")
    offenders = sorted(u for u in below if g.has_edge(u, "config"))
    assert not offenders, f"imported by config and importing it: {offenders}"
    # the owners of the scenario's sections are below it
    assert {"camera", "spectra", "geometry", "renderer", "dem", "detector", "scenes",
            "navigation"} <= below


@pytest.mark.parametrize("lib", ["mitsuba", "drjit"])
def test_only_the_renderer_imports_mitsuba(lib):
    users = sorted({f for unit, mods in IMPORTS.items() for m, f in mods
                    if m.split(".")[0] == lib and unit != "renderer"})
    assert not users, f"{lib} imported outside starnav.renderer: {users}"


def test_cli_is_imported_by_nothing():
    users = sorted({f for unit, mods in IMPORTS.items() for m, f in mods
                    if m.startswith("starnav.cli") and unit != "cli"})
    assert not users, f"starnav.cli imported by {users}"


def test_the_graph_is_read():
    """The checks above see real edges, and the cycle finder finds a cycle that is there (a
    parser that found nothing would pass them)."""
    g = _graph()
    assert g.has_edge("config", "camera") and g.has_edge("simulate", "renderer")
    assert g.has_edge("cli", "simulate") and not g.has_edge("renderer", "config")
    assert "camera" in g.descendants("simulate")
    bad = Graph(g.edges | {("camera", "cli")}, set(g.nodes))
    assert any({"camera", "cli"} <= set(c) for c in bad.cycles())
