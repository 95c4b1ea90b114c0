"""Lines of ``src/starnav`` with the docstrings counted apart, and the module docstrings' lengths.

Usage: ``python tools/src_lines.py [SRC_DIR] [--longest N]``; compare two commits with
``git archive REV src | tar -x -C /tmp/rev`` and the same counter on ``/tmp/rev/src/starnav``.
A docstring is the string that opens a module, class or function (its lines, quotes included);
everything else (code, comments, blank lines) is "code".
"""

from __future__ import annotations

import argparse
import ast
import statistics
from pathlib import Path


def docstring_lines(node: ast.AST) -> int:
    """Lines of the docstring that opens ``node`` (0 without one)."""
    body = getattr(node, "body", None)
    if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant) \
            and isinstance(body[0].value.value, str):
        return body[0].end_lineno - body[0].lineno + 1
    return 0


def count(src: Path) -> tuple[int, int, dict[str, int]]:
    """Total lines, docstring lines, and each module's docstring length by relative path."""
    total = docs = 0
    modules: dict[str, int] = {}
    for path in sorted(src.rglob("*.py")):
        text = path.read_text(encoding="utf-8")
        total += len(text.splitlines())
        tree = ast.parse(text)
        modules[str(path.relative_to(src))] = docstring_lines(tree)
        docs += sum(docstring_lines(n) for n in ast.walk(tree)
                    if isinstance(n, ast.Module | ast.ClassDef | ast.FunctionDef
                                  | ast.AsyncFunctionDef))
    return total, docs, modules


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("src", nargs="?", default=Path(__file__).resolve().parents[1]
                        / "src" / "starnav", type=Path)
    parser.add_argument("--longest", type=int, default=0, help="list the N longest")
    args = parser.parse_args()
    total, docs, modules = count(args.src)
    lengths = list(modules.values())
    print(f"files {len(modules)}  lines {total}  docstrings {docs}  code {total - docs}")
    print(f"module docstrings: median {statistics.median(lengths)}  max {max(lengths)}  "
          f">= 50 lines: {sum(n >= 50 for n in lengths)}  total {sum(lengths)}")
    for name, n in sorted(modules.items(), key=lambda kv: -kv[1])[:args.longest]:
        print(f"{n:5d}  {name}")


if __name__ == "__main__":
    main()
