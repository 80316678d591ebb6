"""mkdocs hooks: the API reference pages list every public name of jaximpact and fitting.

A page under ``docs/api/`` holds a line ``<!-- api: MODULE -->``; the hook replaces it with an
entry for each public name of ``MODULE`` (its ``__all__``, else the names it re-exports with
``from ._x import name as name`` and the ones it defines): a mkdocstrings ``:::`` block for a
class or function (at the module that defines it, so the page follows the code when it moves),
a heading with the ``#:`` comment (or string) above the assignment for a constant. A public
name without a docstring is a warning, so ``mkdocs build --strict`` fails on it;
``tests/test_api_docstrings.py`` runs the same check without mkdocs.
"""

from __future__ import annotations

import ast
import importlib
import importlib.util
import inspect
import logging
import pathlib
import pprint
import re
import sys

log = logging.getLogger("mkdocs.hooks.api")

ROOT = pathlib.Path(__file__).resolve().parents[1]

#: The modules whose public names the API reference lists.
PUBLIC_MODULES = (
    "jaximpact",
    "fitting",
    "jaximpact.sweep",
    "jaximpact.wall_law",
    "jaximpact.reference",
    "jaximpact.tables",
    "jaximpact.parameters",
)

#: Section titles of a page, by the first part of the defining module below the package.
GROUPS = {
    "jaximpact": {
        "_engine": "Simulating impacts",
        "_model": "Scenes",
        "_io": "Scene files and the compilation cache",
        "wall_law": "Capture speed and wall laws",
    },
    "fitting": {
        "_data": "Observations",
        "_scenes": "Scenes",
        "_least_squares": "Least-squares fit and profile likelihood",
        "_bayesian": "Posterior and model comparison",
        "_design": "Experiment design",
    },
}

MARKER = re.compile(r"^<!-- api: ([\w.]+) -->$", re.MULTILINE)


def _module(name: str):
    """The module object ``name`` (``jaximpact.wall_law`` is also a function's name in
    ``jaximpact``, so ``import jaximpact.wall_law as m`` would give the function)."""
    importlib.import_module(name)
    return sys.modules[name]


def _source_tree(module) -> ast.Module:
    return ast.parse(inspect.getsource(module))


def public_names(module_name: str) -> list[str]:
    """The public names of a module: ``__all__``, else its ``name as name`` re-exports and the
    public names it defines at top level."""
    module = _module(module_name)
    if hasattr(module, "__all__"):
        return list(module.__all__)
    names = []
    for node in _source_tree(module).body:
        if isinstance(node, ast.ImportFrom) and node.module != "__future__":
            names += [a.asname for a in node.names if a.asname and a.asname == a.name]
        elif isinstance(node, (ast.FunctionDef, ast.ClassDef)):
            names.append(node.name)
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            names += [t.id for t in targets if isinstance(t, ast.Name)]
    return [n for n in names if not n.startswith("_")]


def _lazy_home(module_name: str, name: str) -> str:
    """The module ``fitting``'s lazy ``__getattr__`` loads ``name`` from (else the module)."""
    exports = getattr(_module(module_name), "_EXPORTS", {})
    if name in exports:
        return importlib.util.resolve_name(exports[name], module_name)
    return module_name


def constant_doc(module_name: str, name: str, _seen=None) -> tuple[str, str] | None:
    """``(defining module, text)`` of constant ``name`` as seen from ``module_name``: the ``#:``
    comment lines above its assignment, or the string right below it; follows imports."""
    seen = _seen if _seen is not None else set()
    if module_name in seen:
        return None
    seen.add(module_name)
    module = _module(module_name)
    source = inspect.getsource(module)
    lines = source.splitlines()
    body = ast.parse(source).body
    package = module_name if hasattr(module, "__path__") else module_name.rpartition(".")[0]
    for i, node in enumerate(body):
        if isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            if not any(isinstance(t, ast.Name) and t.id == name for t in targets):
                continue
            comment = []
            k = node.lineno - 2
            while k >= 0 and lines[k].lstrip().startswith("#:"):
                comment.insert(0, lines[k].lstrip()[2:].strip())
                k -= 1
            text = " ".join(comment)
            after = body[i + 1] if i + 1 < len(body) else None
            if not text and isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant):
                text = inspect.cleandoc(str(after.value.value))
            return module_name, text
        if isinstance(node, ast.ImportFrom) and node.module != "__future__":
            source_module = importlib.util.resolve_name(
                "." * node.level + (node.module or ""), package
            )
            for alias in node.names:
                if alias.name == "*" or (alias.asname or alias.name) == name:
                    imported = name if alias.name == "*" else alias.name
                    found = constant_doc(source_module, imported, seen)
                    if found:
                        return found
    return None


def describe(module_name: str, name: str) -> dict:
    """What the API page shows for ``module_name.name``: ``kind`` (``object`` or ``constant``),
    ``path`` (the defining module's dotted path), ``doc`` (its own docstring or comment)."""
    value = getattr(_module(module_name), name)
    if inspect.isclass(value) or inspect.isfunction(value) or inspect.isroutine(value):
        doc = value.__dict__.get("__doc__") if inspect.isclass(value) else value.__doc__
        if inspect.isclass(value) and (doc or "").startswith(value.__name__ + "("):
            doc = ""  # the signature that dataclasses (and equinox) write where none is given
        return {
            "kind": "object",
            "path": f"{value.__module__}.{value.__qualname__}",
            "doc": (doc or "").strip(),
        }
    found = constant_doc(_lazy_home(module_name, name), name)
    home, doc = found if found else (module_name, "")
    return {"kind": "constant", "path": f"{home}.{name}", "doc": doc, "value": value}


def missing_docstrings() -> list[str]:
    """``module.name`` of each public name without a docstring (or ``#:`` comment)."""
    return [
        f"{m}.{n}" for m in PUBLIC_MODULES for n in public_names(m) if not describe(m, n)["doc"]
    ]


def _group(module_name: str, path: str) -> str | None:
    groups = GROUPS.get(module_name)
    if not groups:
        return None
    part = path.removeprefix(module_name + ".").split(".")[0]
    return groups.get(part, part)


def api_markdown(module_name: str) -> str:
    """The entries of ``module_name``'s public names, grouped as ``GROUPS`` says."""
    entries: dict[str | None, list[str]] = {}
    for name in public_names(module_name):
        d = describe(module_name, name)
        if not d["doc"]:
            log.warning("API reference: %s.%s has no docstring", module_name, name)
        if d["kind"] == "object":
            text = f"::: {d['path']}\n"
        else:
            value = pprint.pformat(d["value"], width=88, compact=True)
            if value.count("\n") > 12:
                value = "\n".join(value.splitlines()[:12]) + "\n..."
            text = (
                f'### `{name}` {{ #{module_name}.{name} data-toc-label="{name}" }}\n\n'
                f"{d['doc']}\n\n```python\n{name} = {value}\n```\n"
            )
        entries.setdefault(_group(module_name, d["path"]), []).append(text)
    order = list(GROUPS.get(module_name, {}).values())
    keys = sorted(entries, key=lambda g: (g is not None, order.index(g) if g in order else 99))
    out = []
    for group in keys:
        if group:
            out.append(f"## {group}\n")
        out += entries[group]
    return "\n".join(out)


def on_page_markdown(markdown, page, config, files):
    return MARKER.sub(lambda m: api_markdown(m.group(1)), markdown)
