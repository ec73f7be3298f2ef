#!/usr/bin/env python3
"""Structural figures of the workspace's sources, read from the text (nothing is imported or run).

    python3 tools/house_metrics.py [--repo DIR] [--json]

Prints, for ``src/``:

- twin functions: pairs of an in-memory and a streaming variant (``f`` beside ``f_streaming``,
  ``Foo`` beside ``StreamedFoo``);
- functions that take 10 or more parameters (``self`` / ``cls`` not counted);
- import circles: strongly connected groups of modules (imports at module level and inside
  functions, relative ones resolved);
- upward arrows: a shared library (``dpos_core``, ``dpos_ros``) importing a node package;
- imports inside functions: all of them, and those of the workspace's own modules;
- exception classes defined outside ``dpos_core.errors``;
- the README's lines, the longest file and the longest function.
"""

from __future__ import annotations

import argparse
import ast
import json
import sys
from pathlib import Path

OWN = ("dpos_core", "dpos_ros", "pos_master_node", "pos_sub_node", "ifa_node", "transfer_align_node", "sar_nav_node")
NODE_PACKAGES = OWN[2:]
ERRORS_MODULES = ("dpos_core.errors",)


def _builtin_exceptions() -> set[str]:
    import builtins
    return {n for n, v in vars(builtins).items() if isinstance(v, type) and issubclass(v, BaseException)}


def _module(src: Path, path: Path) -> str:
    parts = path.relative_to(src).with_suffix("").parts[1:]  # src/<package>/<package>/...
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _sources(src: Path) -> list[Path]:
    return [p for p in sorted(src.glob("*/*/**/*.py")) if "build" not in p.parts and ".egg-info" not in str(p)]


def _imported(node: ast.AST, pkg: list[str]) -> set[str]:
    if isinstance(node, ast.Import):
        return {a.name for a in node.names}
    assert isinstance(node, ast.ImportFrom)
    base = node.module or ""
    if node.level:
        base = ".".join(pkg[: len(pkg) - node.level + 1] + ([base] if base else []))
    return {base} | {f"{base}.{a.name}" for a in node.names}


def _functions(tree: ast.AST) -> list[ast.FunctionDef | ast.AsyncFunctionDef]:
    return [n for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))]


def _sccs(graph: dict[str, set[str]]) -> list[list[str]]:
    """Tarjan's strongly connected components (iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = 0
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on.add(root)
        while work:
            v, it = work[-1]
            for w in it:
                if w not in graph:
                    continue
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                    break
                if w in on:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
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
    return out


def measure(repo: Path) -> dict:
    src = repo / "src"
    builtin_exc = _builtin_exceptions()
    modules: dict[str, set[str]] = {}
    defs: dict[str, list[str]] = {}  # name -> where
    classes: dict[str, list[str]] = {}
    many_params: list[str] = []
    in_function_all: list[str] = []
    in_function_own: list[str] = []
    exceptions: list[str] = []
    longest_file = ("", 0)
    longest_function = ("", 0)
    for path in _sources(src):
        mod = _module(src, path)
        text = path.read_text()
        tree = ast.parse(text, filename=str(path))
        n_lines = len(text.splitlines())
        if n_lines > longest_file[1]:
            longest_file = (str(path.relative_to(repo)), n_lines)
        pkg = mod.split(".") if path.name == "__init__.py" else mod.split(".")[:-1]
        deps: set[str] = set()
        for node in ast.walk(tree):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                deps |= _imported(node, pkg)
        modules[mod] = {d for d in deps if d.split(".")[0] in OWN}
        for fn in _functions(tree):
            where = f"{mod}.{fn.name} ({path.relative_to(repo)}:{fn.lineno})"
            defs.setdefault(fn.name, []).append(where)
            a = fn.args
            names = [x.arg for x in a.posonlyargs + a.args + a.kwonlyargs]
            names = [n for n in names if n not in ("self", "cls")]
            n_params = len(names) + (a.vararg is not None) + (a.kwarg is not None)
            if n_params >= 10:
                many_params.append(f"{where}: {n_params}")
            length = (fn.end_lineno or fn.lineno) - fn.lineno + 1
            if length > longest_function[1]:
                longest_function = (where, length)
            for inner in ast.walk(fn):
                if isinstance(inner, (ast.Import, ast.ImportFrom)):
                    names_in = _imported(inner, pkg)
                    first = sorted(names_in)[0]
                    site = f"{path.relative_to(repo)}:{inner.lineno} {first}"
                    if inner in _direct_imports(fn):
                        in_function_all.append(site)
                        if any(n.split(".")[0] in OWN for n in names_in):
                            in_function_own.append(site)
        for cls in (n for n in ast.walk(tree) if isinstance(n, ast.ClassDef)):
            classes.setdefault(cls.name, []).append(f"{mod}.{cls.name}")
            bases = {b.attr if isinstance(b, ast.Attribute) else getattr(b, "id", "") for b in cls.bases}
            if mod not in ERRORS_MODULES and any(b in builtin_exc or b.endswith(("Error", "Exception", "Failure"))
                                                 for b in bases):
                exceptions.append(f"{mod}.{cls.name}")
    # in-function imports are deduplicated (a nested function's import is its own, not the outer's)
    in_function_all = sorted(set(in_function_all))
    in_function_own = sorted(set(in_function_own))
    twins = sorted({f"{n[: -len('_streaming')]} / {n}" for n in defs if n.endswith("_streaming") and n[: -len("_streaming")] in defs}
                   | {f"{c} / {n}" for n in classes if n.startswith("Streamed") for c in classes
                      if c in (n[len("Streamed"):], n[len("Streamed"):] + "Solution")})
    upward = sorted(f"{m} imports {d}" for m, ds in modules.items() if m.split(".")[0] in ("dpos_core", "dpos_ros")
                    for d in ds if d.split(".")[0] in NODE_PACKAGES)
    graph = {m: {_owner(d, modules) for d in ds} - {m, None} for m, ds in modules.items()}  # type: ignore[misc]
    circles = _sccs({m: {d for d in ds if d} for m, ds in graph.items()})
    readme = repo / "README.md"
    return {
        "twin_functions": twins,
        "functions_10plus_params": sorted(many_params),
        "import_circles": circles,
        "upward_arrows": upward,
        "in_function_imports_all": len(in_function_all),
        "in_function_imports_own": in_function_own,
        "exception_classes_outside_errors": sorted(exceptions),
        "readme_lines": len(readme.read_text().splitlines()) if readme.exists() else 0,
        "longest_file": list(longest_file),
        "longest_function": list(longest_function),
    }


def _direct_imports(fn: ast.AST) -> list[ast.AST]:
    """The import statements of ``fn`` itself, not of the functions nested in it."""
    out: list[ast.AST] = []
    todo = list(ast.iter_child_nodes(fn))
    while todo:
        n = todo.pop()
        if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            continue
        if isinstance(n, (ast.Import, ast.ImportFrom)):
            out.append(n)
        todo.extend(ast.iter_child_nodes(n))
    return out


def _owner(name: str, modules: dict[str, set[str]]) -> str | None:
    """The module a dotted import name lands in (``pkg.mod.func`` -> ``pkg.mod``)."""
    parts = name.split(".")
    for k in range(len(parts), 0, -1):
        cand = ".".join(parts[:k])
        if cand in modules:
            return cand
    return None


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repo", type=Path, default=Path(__file__).resolve().parents[1])
    ap.add_argument("--json", action="store_true", help="print every item as JSON, not the summary")
    ap.add_argument("--list", action="store_true", help="list the items under each count")
    args = ap.parse_args(argv)
    m = measure(args.repo)
    if args.json:
        print(json.dumps(m, indent=1))
        return 0
    rows = [
        ("twin functions (in-memory / streaming)", len(m["twin_functions"]), m["twin_functions"]),
        ("functions with 10+ parameters", len(m["functions_10plus_params"]), m["functions_10plus_params"]),
        ("import circles", len(m["import_circles"]), [" <-> ".join(c) for c in m["import_circles"]]),
        ("upward arrows (library -> node package)", len(m["upward_arrows"]), m["upward_arrows"]),
        ("imports inside functions, all", m["in_function_imports_all"], []),
        ("imports inside functions, own modules", len(m["in_function_imports_own"]), m["in_function_imports_own"]),
        ("exception classes outside dpos_core.errors", len(m["exception_classes_outside_errors"]),
         m["exception_classes_outside_errors"]),
        ("README lines", m["readme_lines"], []),
        ("longest file (lines)", f"{m['longest_file'][1]} {m['longest_file'][0]}", []),
        ("longest function (lines)", f"{m['longest_function'][1]} {m['longest_function'][0]}", []),
    ]
    for label, value, items in rows:
        print(f"{label:45s} {value}")
        if args.list:
            for it in items:
                print(f"    {it}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
