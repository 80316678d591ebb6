"""Code size: the largest modules and longest functions of the packages, and import circles.

The rule (issue 53): no module above 600 lines, no function above 80 lines (``def`` to its
last line, docstring included), and no import circle between the modules of a package.

``python tools/code_size.py`` prints, for ``jaximpact`` and ``fitting``, the five largest
modules and the five longest functions, then every module and function over its limit and
every import circle, and exits 1 if there is any; ``--package jaximpact`` checks one package
(the option may be repeated). Standard library only (no import of the packages themselves).
"""

from __future__ import annotations

import argparse
import ast
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("jaximpact", "fitting")
MODULE_LINES = 600
FUNCTION_LINES = 80
SHOWN = 5


def modules(package: str) -> dict[str, Path]:
    """The package's modules by dotted name (a package by its ``__init__.py``)."""
    root = ROOT / package
    out = {}
    for path in sorted(root.rglob("*.py")):
        parts = list(path.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def module_lines(path: Path) -> int:
    return len(path.read_text(encoding="utf-8").splitlines())


def functions(path: Path) -> list[tuple[int, str, int]]:
    """``(lines, qualified name, first line)`` of every function and method in ``path``."""
    out = []

    def visit(node, prefix):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef):
                name = f"{prefix}{child.name}"
                out.append((child.end_lineno - child.lineno + 1, name, child.lineno))
                visit(child, f"{name}.")
            elif isinstance(child, ast.ClassDef):
                visit(child, f"{prefix}{child.name}.")
            else:
                visit(child, prefix)

    visit(ast.parse(path.read_text(encoding="utf-8")), "")
    return out


def imports(name: str, path: Path, known: dict[str, Path]) -> set[str]:
    """The package's modules that ``name`` imports (at module level or inside a function).
    A module's own ancestor packages are left out: Python imports them before it."""
    is_package = path.name == "__init__.py"
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = name.split(".")
                if not is_package:
                    base = base[:-1]
                base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            subs = [f"{target}.{a.name}" for a in node.names if f"{target}.{a.name}" in known]
            # ``from package import module``: the module (the package is its ancestor)
            found = subs if len(subs) == len(node.names) else [target, *subs]
        elif isinstance(node, ast.Import):
            found = [a.name for a in node.names]
        else:
            continue
        out.update(m for m in found if m in known and m != name and not name.startswith(m + "."))
    return out


def import_circles(known: dict[str, Path]) -> list[list[str]]:
    """The strongly connected components (more than one module) of the import graph."""
    graph = {name: sorted(imports(name, path, known)) for name, path in known.items()}
    index, low, stack, on_stack, circles = {}, {}, [], set(), []

    def connect(v):  # Tarjan's algorithm
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                connect(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                circles.append(sorted(component))

    for v in graph:
        if v not in index:
            connect(v)
    return circles


def check(package: str) -> list[str]:
    """Print the package's largest modules and longest functions; return its violations."""
    known = modules(package)
    sizes = sorted(((module_lines(p), p) for p in known.values()), reverse=True)
    funcs = sorted(
        ((n, f"{p.relative_to(ROOT)}:{line} {name}") for p in known.values()
         for n, name, line in functions(p)),
        reverse=True,
    )  # fmt: skip
    print(f"{package}: the {SHOWN} largest modules (lines)")
    for n, p in sizes[:SHOWN]:
        print(f"  {n:5d}  {p.relative_to(ROOT)}")
    print(f"{package}: the {SHOWN} longest functions (lines)")
    for n, where in funcs[:SHOWN]:
        print(f"  {n:5d}  {where}")
    problems = [
        f"module {p.relative_to(ROOT)}: {n} lines (limit {MODULE_LINES})"
        for n, p in sizes
        if n > MODULE_LINES
    ]
    problems += [
        f"function {where}: {n} lines (limit {FUNCTION_LINES})"
        for n, where in funcs
        if n > FUNCTION_LINES
    ]
    problems += [f"import circle: {' <-> '.join(c)}" for c in import_circles(known)]
    return problems


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--package",
        action="append",
        choices=PACKAGES,
        help="check this package only (may be repeated; default: all of them)",
    )
    args = parser.parse_args(argv)
    problems = []
    for package in args.package or PACKAGES:
        problems += check(package)
    if problems:
        print(f"\n{len(problems)} over the limits:")
        for p in problems:
            print(f"  {p}")
        return 1
    print("\nwithin the limits")
    return 0


if __name__ == "__main__":
    sys.exit(main())
