"""The dependency graph the architecture promises (docs/architecture.md; issue 14).

Read from the source with :mod:`ast`: every ``import`` of the package, at module level or inside
a function, ``TYPE_CHECKING`` blocks included (a type-only import still points the wrong way).
"""

from __future__ import annotations

import ast
import re
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


#: Units that stay below others within a layer: never import them, directly or through a third
#: unit. The target body is the data model the renderer draws (shape, photometry, spin).
BELOW = {"bodies": {"renderer"}}


def _above_reached(g: Graph) -> list[tuple[str, str]]:
    """``(unit, unit above it)`` for every :data:`BELOW` pair the graph reaches upwards."""
    return sorted((a, b) for a, above in BELOW.items() for b in above if b in g.descendants(a))


def test_the_body_is_below_the_renderer():
    g = _graph()
    assert g.has_edge("renderer", "bodies"), "the renderer draws the body's model"
    assert not _above_reached(g), f"imports that run back up: {_above_reached(g)}"
    # the check sees a direct import of the renderer from bodies, and one through a third unit
    assert _above_reached(Graph(g.edges | {("bodies", "renderer")}, set(g.nodes)))
    assert _above_reached(Graph(g.edges | {("bodies", "show")}, set(g.nodes)))


def test_the_graph_is_read():
    """The checks above see real edges, and the cycle finder finds a cycle that is there (a
    parser that found nothing would pass them)."""
    g = _graph()
    assert g.has_edge("config", "camera") and g.has_edge("simulate", "renderer")
    assert g.has_edge("cli", "simulate") and not g.has_edge("renderer", "config")
    assert "camera" in g.descendants("simulate")
    bad = Graph(g.edges | {("camera", "cli")}, set(g.nodes))
    assert any({"camera", "cli"} <= set(c) for c in bad.cycles())


# ------------------------------------------------------------------ function-level imports
#: Why a function may import a starnav module instead of the module's head (the only reasons):
#: an import cycle at load, Mitsuba/Dr.Jit (starnav.renderer only), or a heavy optional library.
LAZY_REASON = re.compile(r"#\s*lazy:\s*(cycle with (starnav(?:\.\w+)+)|mitsuba|drjit"
                         r"|[\w./]+ \(heavy\))")


def _is_starnav(node: ast.Import | ast.ImportFrom) -> bool:
    if isinstance(node, ast.ImportFrom):
        return node.level > 0 or (node.module or "").split(".")[0] == "starnav"
    return any(a.name.split(".")[0] == "starnav" for a in node.names)


def function_imports(source: str) -> list[tuple[int, str, re.Match[str] | None]]:
    """``(line, source line, reason)`` of every import of a starnav module (absolute or
    relative) written inside a function; ``reason`` matches :data:`LAZY_REASON` on one of the
    statement's lines, or is None."""
    lines = source.splitlines()
    out = []

    def visit(node: ast.AST, in_function: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if (in_function and isinstance(child, ast.Import | ast.ImportFrom)
                    and _is_starnav(child)):
                stmt = lines[child.lineno - 1:child.end_lineno]
                reason = next((m for m in map(LAZY_REASON.search, stmt) if m), None)
                out.append((child.lineno, lines[child.lineno - 1].strip(), reason))
            visit(child, in_function or isinstance(
                child, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda))

    visit(ast.parse(source), False)
    return out


def test_function_level_imports_are_explained():
    """A module's starnav dependencies are at its top; an import inside a function says why
    (``# lazy: cycle with starnav.x``, ``# lazy: mitsuba``, ``# lazy: matplotlib (heavy)``).
    The command line (starnav.cli) imports inside its commands to keep ``--help`` fast."""
    found, bad = [], []
    for f in sorted(SRC.rglob("*.py")):
        rel = f.relative_to(SRC)
        if rel.parts[0] == "cli":
            continue
        for line, text, reason in function_imports(f.read_text()):
            found.append((rel, line))
            if reason is None:
                bad.append(f"{rel}:{line}: {text}")
            elif reason.group(2) and not _module_file(reason.group(2)):
                bad.append(f"{rel}:{line}: {text} (no module {reason.group(2)})")
    assert not bad, (f"{len(found)} function-level imports of starnav modules outside "
                     f"starnav.cli, {len(bad)} without a '# lazy: <reason>' comment (a cycle "
                     "with starnav.x, mitsuba, drjit or '<library> (heavy)'); move them to the "
                     "module's top or say why:\n" + "\n".join(bad))


def _module_file(module: str) -> bool:
    path = SRC.parent.joinpath(*module.split("."))
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def test_function_imports_are_read():
    """The check above sees an unexplained import, nested or relative, and accepts the
    reasons."""
    src = ("import starnav.camera\n"
           "def f():\n"
           "    from starnav.config import Scenario\n"
           "    import numpy\n"
           "    if True:\n"
           "        from . import geometry\n"
           "    from starnav.dem.load import (  # lazy: cycle with starnav.dem.load\n"
           "        load_dem,\n"
           "    )\n"
           "    import starnav.renderer.bsdfs  # lazy: mitsuba\n"
           "    from starnav.batch import figures  # lazy: matplotlib (heavy)\n"
           "    from starnav.x import y  # lazy: because\n"
           "class A:\n"
           "    def g(self):\n"
           "        return lambda: __import__('starnav')\n")
    got = {line: r is not None for line, _, r in function_imports(src)}
    assert got == {3: False, 6: False, 7: True, 10: True, 11: True, 12: False}
    assert _module_file("starnav.dem.load") and not _module_file("starnav.dem.nowhere")


# --------------------------------------------------------------------------- SI at the edge
#: Where a scenario key may still be read in its own unit (``range_km``, ``row_time_us``):
#: the builders of a subsystem's SI objects, and text that quotes the user's values back.
#: Everywhere else reads ``section.to_si()`` (or the object built from it). A single line may
#: opt out with a ``# unit:`` comment saying why.
UNIT_READERS = {
    "dem/": "the DEM loaders build DemGrid/AlbedoGrid (SI) from moon.dem",
    "calibration/": "Bench.from_config builds the bench (SI); its report quotes lab units",
    "reference/": "AMIE label units, converted where the label is read",
    "batch/report.py": "the sweep report quotes the scenario's values in its units",
    "show.py": "the 3-D view is drawn in km",
    "scenes/schema.py": "validators compare two keys of the same unit",
}


def _unit_keys() -> set[str]:
    """Every scenario key whose unit is not SI (the SI view converts it)."""
    import typing

    from pydantic import BaseModel

    from starnav.config import Scenario
    from starnav.config_base import si_name

    keys: set[str] = set()

    def walk(model: type[BaseModel]) -> None:
        for k, f in model.model_fields.items():
            _, conv = si_name(k)
            if conv is not None and conv != (1.0, 0.0):
                keys.add(k)
            for a in (f.annotation, *typing.get_args(f.annotation)):
                for b in (a, *typing.get_args(a)):
                    if isinstance(b, type) and issubclass(b, BaseModel):
                        walk(b)

    walk(Scenario)
    return keys


def test_scenario_units_are_converted_in_one_place():
    keys = _unit_keys()
    assert {"row_time_us", "a_ms", "range_km", "phase_angle_deg", "temperature_c",
            "knowledge_roll_arcsec"} <= keys
    bad = []
    for f in sorted(SRC.rglob("*.py")):
        rel = f.relative_to(SRC).as_posix()
        if rel.startswith("cli/") or any(rel.startswith(p) for p in UNIT_READERS):
            continue
        text = f.read_text()
        lines = text.splitlines()
        for node in ast.walk(ast.parse(text)):
            if (isinstance(node, ast.Attribute) and node.attr in keys
                    and isinstance(node.ctx, ast.Load)
                    and "# unit:" not in lines[node.lineno - 1]):
                bad.append(f"{rel}:{node.lineno}: .{node.attr}")
    assert not bad, "read the SI view (to_si()) instead:\n" + "\n".join(bad)


# ------------------------------------------------------------------ the code says what and why
#: What narrates instead of describing: an issue number, a calendar date (an ISO date-time such
#: as an epoch ``2027-03-01T00:00:00`` is data, not narration), a design file that is not in the
#: repository.
NARRATION = re.compile(r"\bissue[- ]?\d+|\b20\d\d-\d\d-\d\d(?!T)|DESIGN\.md", re.IGNORECASE)


def _narration(text: str) -> list[str]:
    return [line.strip() for line in text.splitlines() if NARRATION.search(line)]


def test_the_narration_check_catches_what_it_names():
    """The check itself: each pattern is caught, epochs and plain numbers are not."""
    assert _narration("made faster (issue 18)")
    assert _narration("the issue-8 dataset format")
    assert _narration("measured 2026-11-27 09:05 UTC")
    assert _narration("conventions (DESIGN.md)")
    assert not _narration('DEFAULT_EPOCH = "2027-03-01T00:00:00 TDB"')
    assert not _narration("ISO 2000 and 2 issues with 18 frames")


def test_src_does_not_narrate():
    """No issue numbers, dates or references to files outside the repository in ``src/``:
    history belongs in git, measurements in ``docs/performance.md`` and the benchmarks."""
    found = {str(f.relative_to(SRC)): hits for f in sorted(SRC.rglob("*.py"))
             if (hits := _narration(f.read_text()))}
    assert not found, found


def test_float_array_is_declared_once():
    """One array alias for the package (``starnav.typing``), not one per module."""
    pattern = re.compile(r"^FloatArray\s*=", re.M)
    where = sorted(str(f.relative_to(SRC)) for f in SRC.rglob("*.py")
                   if pattern.search(f.read_text()))
    assert where == ["typing.py"], where


# ------------------------------------------------------------------ short module docstrings
#: A module docstring is a summary, its references and an index (the numpydoc habit); the
#: technique in full lives in docs/methods.md and the subsystem pages. Bounds on its length in
#: lines: the median over the package and the longest one.
MODULE_DOCSTRING_MEDIAN_LINES = 22
MODULE_DOCSTRING_MAX_LINES = 50
_DOCSTRING = re.compile(r'\s*(?:#[^\n]*\n\s*)*([rRuU]?"""(?:.|\n)*?""")')


def _module_docstring_lines(text: str) -> int:
    """Lines of a module's docstring, quotes included (0 without one): the leading
    triple-quoted string (read as text: parsing every module would cost seconds)."""
    m = _DOCSTRING.match(text)
    return m.group(1).count("\n") + 1 if m else 0


def test_the_docstring_counter_counts_lines():
    assert _module_docstring_lines('"""One line."""\nx = 1\n') == 1
    assert _module_docstring_lines('"""Summary.\n\nIndex\n-----\nf\n"""\n') == 6
    assert _module_docstring_lines("x = 1\n") == 0
    assert _module_docstring_lines('# comment\nr"""A\nB."""\n') == 2


def test_module_docstrings_are_short():
    """Median and longest module docstring of ``src/`` within their bounds."""
    lengths = {str(f.relative_to(SRC)): _module_docstring_lines(f.read_text())
               for f in sorted(SRC.rglob("*.py"))}
    longest = sorted(lengths.items(), key=lambda kv: -kv[1])[:5]
    assert float(np.median(list(lengths.values()))) <= MODULE_DOCSTRING_MEDIAN_LINES, longest
    too_long = {k: n for k, n in lengths.items() if n > MODULE_DOCSTRING_MAX_LINES}
    assert not too_long, f"module docstrings over {MODULE_DOCSTRING_MAX_LINES} lines: {too_long}"


# ------------------------------------------------------------------ one driver of the runs
#: A name that counts or numbers Monte Carlo runs (``runs``, ``n_runs``, ``first_run``,
#: ``run_ids``, ``self.runs``).
RUN_NAME = re.compile(r"(?:^|_)runs?(?:$|_)")


def _names(node: ast.AST) -> set[str]:
    return {n.id if isinstance(n, ast.Name) else n.attr for n in ast.walk(node)
            if isinstance(n, ast.Name | ast.Attribute)}


def run_loops(source: str) -> list[tuple[int, str]]:
    """``(line, source line)`` of every loop over Monte Carlo runs: a ``for`` statement or a
    comprehension whose iterable is, or contains, ``range(...)`` of a run count or number
    (:data:`RUN_NAME`), a call of ``run_ids(...)``, or the run numbers themselves
    (``for r in run_ids``). A loop over the runs' results (``for res in loop.runs``) is not
    one: it repeats no run."""
    lines = source.splitlines()
    out = set()
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, ast.For | ast.AsyncFor | ast.comprehension):
            continue
        it = node.iter
        calls = [c for c in ast.walk(it) if isinstance(c, ast.Call)
                 and isinstance(c.func, ast.Name) and c.func.id in ("range", "run_ids")]
        hit = any(c.func.id == "run_ids"  # type: ignore[union-attr]
                  or any(RUN_NAME.search(n) for a in c.args for n in _names(a))
                  for c in calls)
        if hit or (isinstance(it, ast.Name) and it.id == "run_ids"):
            out.add((it.lineno, lines[it.lineno - 1].strip()))
    return sorted(out)


def test_the_run_loop_check_catches_what_it_names():
    """The check below: loops over a range of runs (statement, comprehension, enumerate) and
    over run numbers are caught; loops over other ranges, over the runs' results and the
    driver's call are not."""
    src = ("for r in range(runs):\n"                                   # 1
           "    pass\n"
           "out = [f(r) for r in range(1, n_runs + 1)]\n"              # 3
           "for k, r in enumerate(range(first_run, first_run + runs)):\n"  # 4
           "    pass\n"
           "for r in run_ids:\n"                                       # 6
           "    pass\n"
           "x = {r: g(r) for r in range(self.runs)}\n"                 # 8
           "for j in range(6):\n"
           "    pass\n"
           "for res in loop.runs:\n"
           "    pass\n"
           "nees = [r.nees(x) for r in results]\n"
           "for k in range(len(frames)):\n"
           "    pass\n"
           "done = over_runs(one_run, runs)\n"
           "for runs in (2, 4):\n"
           "    pass\n"
           "y = [h(r) for r in run_ids(4, 1)]\n")                      # 19
    assert [line for line, _ in run_loops(src)] == [1, 3, 4, 6, 8, 19]


#: The one driver of the runs.
RUN_DRIVER = "batch/runs.py"


def test_runs_are_looped_over_by_the_batch_driver_only():
    """Every loop over Monte Carlo runs goes through the one driver in ``starnav.batch``
    (:mod:`starnav.batch.runs`): ``simulate`` makes a run's frames and ``navigation``
    estimates on them; neither repeats them, and no other batch module loops on its own."""
    texts = {f: f.read_text() for f in sorted(SRC.rglob("*.py"))
             if f.relative_to(SRC).as_posix() != RUN_DRIVER}
    found = [f"{f.relative_to(SRC)}:{line}: {text}" for f, src in texts.items()
             if "range(" in src or "run_ids" in src  # no loop over runs without either
             for line, text in run_loops(src)]
    assert not found, f"loop over runs outside {RUN_DRIVER} (map a per-run function with " \
        "starnav.batch.runs.over_runs):\n" + "\n".join(found)


# ------------------------------------------------------------------ one declaration per knob
#: A unit suffix an SI options field may carry where its scenario key carries the user's unit
#: (``max_phase_rad`` for ``max_phase_deg``, ``bias_tau_s`` for ``bias_tau_days``).
_SI_FIELD_SUFFIX = re.compile(r"_(m|s|rad|m_s|m2_s3)$")
#: Dataclass fields named as a knob that hold something else: what the builder resolves from
#: a knob and the scenario, or what an algorithm reports. Each with its reason; every other
#: dataclass of a section's module holds no knob of the section (no allowlist of repeats: a
#: knob is declared on its schema field and the algorithm reads the section's SI view).
RESOLVED = {
    # fix.attitude_sigma_arcsec, null: the pointing section's knowledge; or a star solution's
    # 3 x 3 covariance (navigation.attitude: stars)
    "starnav.navigation.christian_robinson.ChristianRobinsonOptions.attitude_sigma_rad",
    # the model a RANSAC result was fitted with (a record of the output, not a setting)
    "starnav.navigation.ransac.RansacResult.model",
    # the packaged calibration's value, what refine.saturated_model_error_px: null resolves to
    "starnav.navigation.refine.ModelErrorCalibration.saturated_model_error_px",
}


def _section_modules(section: type) -> set[str]:
    """The modules a schema section belongs to: where it is defined, and the
    ``starnav.navigation`` modules its docstring names as its reader."""
    named = re.findall(r"starnav\.navigation(?:\.\w+)+", section.__doc__ or "")
    return {section.__module__, *named}


def _dataclass_fields(text: str, module: str) -> dict[str, list[str]]:
    """``module.Name`` -> field names of each ``@dataclass`` class in the source ``text``
    (options, resolved models, results: a knob repeated under any name of class is caught;
    read with :mod:`ast`: importing every module would load OpenCV and Matplotlib)."""
    out = {}
    for node in ast.parse(text).body:
        if (isinstance(node, ast.ClassDef)
                and any("dataclass" in ast.unparse(d) for d in node.decorator_list)):
            out[f"{module}.{node.name}"] = [
                b.target.id for b in node.body
                if isinstance(b, ast.AnnAssign) and isinstance(b.target, ast.Name)
                and not ast.unparse(b.annotation).startswith("ClassVar")]
    return out


def _repeated_knobs(options: dict[str, list[str]], sections: list[type]) -> dict[str, list[str]]:
    """``module.Options`` -> the fields that repeat a key of a schema section of its module
    (compared with and without the key's unit suffix, the field without an SI suffix)."""
    out = {}
    for here, fields in options.items():
        module = here.rsplit(".", 1)[0]
        keys: set[str] = set()
        for s in sections:
            if module in _section_modules(s):
                keys |= set(s.model_fields) | set(s().to_si().keys())
        rep = sorted(f for f in fields
                     if (f in keys or _SI_FIELD_SUFFIX.sub("", f) in keys)
                     and f"{here}.{f}" not in RESOLVED)
        if rep:
            out[here] = rep
    return out


def _navigation_sections() -> list[type]:
    """Every section of the scenario's ``navigation`` (nested ones included)."""
    from starnav.config_base import StrictModel
    from starnav.navigation.schema import NavigationConfig

    found, todo = [], [NavigationConfig]
    while todo:
        s = todo.pop()
        found.append(s)
        for f in s.model_fields.values():
            ann = f.annotation
            if isinstance(ann, type) and issubclass(ann, StrictModel) and ann not in found:
                todo.append(ann)
    return found


def _navigation_dataclasses() -> dict[str, list[str]]:
    """The dataclasses of ``starnav.navigation`` and their fields."""
    out = {}
    for f in sorted((SRC / "navigation").rglob("*.py")):
        module = ".".join(("starnav", *f.relative_to(SRC).with_suffix("").parts))
        out.update(_dataclass_fields(f.read_text(), module.removesuffix(".__init__")))
    return out


def test_the_repeated_knob_check_catches_what_it_names():
    """The check itself: a dataclass beside its section that repeats a key (as it is, or in SI
    with its unit), whatever its class is called, is caught; one that holds only what the
    section does not, a section of another module, or a class that is not a dataclass, is
    not."""
    from pydantic import Field

    from starnav.config_base import StrictModel

    class DemoConfig(StrictModel):
        """A section (starnav.navigation.demo)."""

        threshold_px: float = Field(2.0, description="inlier threshold [px]")
        tau_days: float = Field(1.0, description="correlation time [days]")

    source = (
        "@dataclass(frozen=True)\nclass DemoOptions:\n    threshold_px: float = 2.0\n"
        "    tau_s: float = 86400.0\n    batch: int = 32\n\n"
        "@dataclass\nclass OtherOptions:\n    batch: int = 32\n\n"
        "@dataclass(frozen=True)\nclass DemoModels:\n    noise: object = None\n"
        "    tau_days: float = 1.0\n\n"
        "class PlainOptions:\n    threshold_px: float = 2.0\n")
    found = _dataclass_fields(source, "starnav.navigation.demo")
    assert set(found) == {"starnav.navigation.demo.DemoOptions",
                          "starnav.navigation.demo.OtherOptions",
                          "starnav.navigation.demo.DemoModels"}
    assert _repeated_knobs(found, [DemoConfig]) == {
        "starnav.navigation.demo.DemoOptions": ["tau_s", "threshold_px"],
        "starnav.navigation.demo.DemoModels": ["tau_days"]}
    assert _repeated_knobs(_dataclass_fields(source, "starnav.navigation.other"),
                           [DemoConfig]) == {}


def test_each_navigation_knob_is_declared_once():
    """No dataclass of the navigation repeats a knob of its scenario section: the algorithms
    read the section's SI view (``to_si()``), as the detector does, and what the builder
    resolves sits in dataclasses of resolved objects (``RefineModels``, ``EkfPriors``)."""
    options = _navigation_dataclasses()
    for scanned in ("pipeline.ChainOptions", "refine.RefineModels", "ekf.EkfPriors"):
        assert f"starnav.navigation.{scanned}" in options   # the scan reads them
    found = _repeated_knobs(options, _navigation_sections())
    assert not found, ("a knob declared twice (declare it once, on its schema field, and read "
                       f"the section's SI view): {found}")
    fields = {f"{k}.{f}" for k, v in options.items() for f in v}
    assert RESOLVED <= fields, f"stale RESOLVED entries: {sorted(RESOLVED - fields)}"
