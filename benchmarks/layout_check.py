"""Layout of the balance_opt package, read from its source with ``ast`` (nothing is imported).

Prints four tables:

* the modules directly in ``balance_opt/`` (the top level should stay small);
* the largest modules, in lines (the rule: none over 600);
* the functions over 80 lines, with ``file:line`` and whether a reason is given: a comment
  containing ``long:`` on the ``def`` line or on the line above the function (above its
  decorators, if any);
* the imports that run up the declared layers (:data:`LAYERS`: a module may import from its own
  layer and the layers listed before it), the import cycles between balance_opt modules, and
  those between parts (a subpackage or a module directly in the package is one node: two parts
  of one layer that import each other are a cycle even when no modules are). All count imports
  at any depth (inside functions too) but not those under
  ``if TYPE_CHECKING:``, which never run. An import ``from balance_opt.a import b`` is an edge
  to the module ``balance_opt.a.b`` when there is one, else to ``balance_opt.a`` (importing a
  module also runs its parent packages' ``__init__``; those implicit edges are not counted, as
  every import tool does).

Exits 1 when an import runs upward, a cycle (of modules or of parts) exists or a part of the
package is in no layer. The size and function tables only report, unless ``--sizes`` is given:
then a module over 600 lines or a function over ``--max-lines`` (a ``long:`` reason or not) fails
too, and the last line counts them.

    python benchmarks/layout_check.py [--package PATH] [--top 10] [--max-lines 80] [--sizes]
"""

from __future__ import annotations

import argparse
import ast
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MODULE_LIMIT = 600
REASON_MARK = "long:"
MAX_CYCLES_PER_GROUP = 20

#: The declared layers, lowest first: ``(layer, parts)``. A part is a subpackage or a module
#: directly in the package (``""`` is the package's ``__init__``, the notebook API). A module
#: imports only from its own layer and those before it; parts of one layer may import each
#: other one way only (no cycle of parts).
LAYERS = (
    ("base", ("errors", "interrupts", "progress", "cache")),
    ("solvers", ("solvers",)),
    ("config", ("config",)),
    ("model", ("model",)),
    ("geometry", ("geometry",)),
    ("motion", ("motion",)),
    ("analytic", ("analytic",)),
    ("optimal", ("optimal",)),
    ("dynamics", ("dynamics",)),
    ("control", ("control",)),
    ("tasks", ("tasks",)),
    ("report", ("report",)),
    ("app", ("app",)),
    ("sweep", ("sweep",)),
    ("cli", ("commands", "cli", "")),
)


def module_name(path: Path, package_dir: Path) -> str:
    """``balance_opt/sweep/spec.py`` -> ``balance_opt.sweep.spec`` (``__init__`` -> package)."""
    parts = list(path.relative_to(package_dir.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _runtime_imports(tree: ast.AST):
    """Import nodes at any depth, skipping the bodies of ``if TYPE_CHECKING:``."""
    stack = [tree]
    while stack:
        node = stack.pop()
        if isinstance(node, ast.If) and _is_type_checking(node.test):
            stack.extend(node.orelse)
            continue
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node
        stack.extend(ast.iter_child_nodes(node))


def import_edges(name: str, is_package: bool, tree: ast.AST, modules: set[str]) -> set[str]:
    """The balance_opt modules that module ``name`` imports."""
    top = name.split(".")[0]
    edges = set()
    for node in _runtime_imports(tree):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        else:
            if node.level:  # relative: resolve against this module's package
                base = name.split(".") if is_package else name.split(".")[:-1]
                base = base[: len(base) - (node.level - 1)]
                origin = ".".join(base + ([node.module] if node.module else []))
            else:
                origin = node.module or ""
            targets = [
                f"{origin}.{alias.name}" if f"{origin}.{alias.name}" in modules else origin
                for alias in node.names
            ]
        for target in targets:
            while target and target not in modules:  # "import a.b.c" of a name, not a module
                target = target.rpartition(".")[0]
            if target and target.split(".")[0] == top and target != name:
                edges.add(target)
    return edges


def part_of(module: str) -> str:
    """``balance_opt.sweep.spec`` -> ``sweep``; the package itself -> ``""``."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def layer_index() -> dict[str, int]:
    """``part -> position of its layer in`` :data:`LAYERS`."""
    return {part: i for i, (_, parts) in enumerate(LAYERS) for part in parts}


def upward_imports(graph: dict[str, set[str]]) -> list[tuple[str, str, str, str]]:
    """``(module, imported module, its layer, the imported one's layer)`` of every import from a
    lower layer to a higher one."""
    rank, names = layer_index(), [name for name, _ in LAYERS]
    found = []
    for module in sorted(graph):
        for target in sorted(graph[module]):
            a, b = rank.get(part_of(module)), rank.get(part_of(target))
            if a is not None and b is not None and b > a:
                found.append((module, target, names[a], names[b]))
    return found


def part_graph(graph: dict[str, set[str]]) -> dict[str, set[str]]:
    """The imports between parts (:func:`part_of`): ``part -> parts it imports`` (not itself)."""
    parts = {part_of(m): set() for m in graph}
    for module, targets in graph.items():
        parts[part_of(module)] |= {part_of(t) for t in targets} - {part_of(module)}
    return parts


def long_functions(tree: ast.AST, lines: list[str], limit: int):
    """``(line, qualified name, length, reason given)`` of every function over ``limit`` lines."""
    found = []

    def visit(node, prefix):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                qual = f"{prefix}{child.name}"
                if not isinstance(child, ast.ClassDef):
                    length = child.end_lineno - child.lineno + 1
                    if length > limit:
                        first = min([child.lineno] + [d.lineno for d in child.decorator_list])
                        above = lines[first - 2] if first >= 2 else ""
                        reason = REASON_MARK in lines[child.lineno - 1] or (
                            above.lstrip().startswith("#") and REASON_MARK in above
                        )
                        found.append((child.lineno, qual, length, reason))
                visit(child, qual + ".")
            else:
                visit(child, prefix)

    visit(tree, "")
    return found


def strongly_connected(graph: dict[str, set[str]]) -> list[list[str]]:
    """Tarjan's strongly connected components (iterative), those of more than one module."""
    index, low, on_stack, stack, groups, counter = {}, {}, set(), [], [], [0]
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter[0]
        counter[0] += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = counter[0]
                    counter[0] += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                group = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    group.append(member)
                    if member == node:
                        break
                if len(group) > 1:
                    groups.append(sorted(group))
    return groups


def simple_cycles(graph: dict[str, set[str]], group: list[str], cap: int) -> list[list[str]]:
    """Elementary cycles inside one component, each started at its smallest module (at most
    ``cap``)."""
    members, cycles = set(group), []
    for start in group:
        path, stack = [start], [iter(sorted(graph[start] & members))]
        while stack and len(cycles) < cap:
            child = next(stack[-1], None)
            if child is None:
                stack.pop()
                path.pop()
            elif child == start:
                cycles.append([*path, start])
            elif child > start and child not in path:
                path.append(child)
                stack.append(iter(sorted(graph[child] & members)))
    return cycles


def table(rows: list[tuple], header: tuple) -> str:
    rows = [tuple(str(c) for c in r) for r in rows]
    widths = [max(len(str(h)), *(len(r[i]) for r in rows)) for i, h in enumerate(header)]
    line = "  ".join("-" * w for w in widths)
    fmt = "  ".join(f"{{:<{w}}}" for w in widths)
    return "\n".join([fmt.format(*header), line, *(fmt.format(*r) for r in rows)])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--package", type=Path, default=ROOT / "balance_opt")
    parser.add_argument("--top", type=int, default=10, help="largest modules shown")
    parser.add_argument("--max-lines", type=int, default=80, help="longest function allowed")
    parser.add_argument(
        "--sizes",
        action="store_true",
        help=f"fail on a module over {MODULE_LIMIT} lines or a function over --max-lines",
    )
    args = parser.parse_args(argv)
    package = args.package.resolve()
    files = sorted(package.rglob("*.py"))
    modules = {module_name(p, package): p for p in files}
    sources = {name: p.read_text(encoding="utf-8") for name, p in modules.items()}
    trees = {name: ast.parse(text, str(modules[name])) for name, text in sources.items()}
    rel = {name: p.relative_to(package.parent).as_posix() for name, p in modules.items()}

    top_level = [p for p in files if p.parent == package]
    print(f"modules directly in {package.name}/: {len(top_level)}")
    print("  " + ", ".join(p.name for p in top_level))
    print(
        f"subpackages: {', '.join(sorted(d.name for d in package.iterdir() if (d / '__init__.py').is_file()))}"
    )

    sizes = sorted(((len(s.splitlines()), n) for n, s in sources.items()), reverse=True)
    over = sum(1 for lines, _ in sizes if lines > MODULE_LIMIT)
    print(f"\nlargest modules ({len(files)} modules, {over} over {MODULE_LIMIT} lines)")
    print(
        table(
            [
                (rel[n], lines, "OVER" if lines > MODULE_LIMIT else "")
                for lines, n in sizes[: args.top]
            ],
            ("module", "lines", ""),
        )
    )

    long_rows = []
    for name, tree in trees.items():
        for line, qual, length, reason in long_functions(
            tree, sources[name].splitlines(), args.max_lines
        ):
            long_rows.append((f"{rel[name]}:{line}", qual, length, "yes" if reason else "NO"))
    long_rows.sort(key=lambda r: -r[2])
    missing = sum(1 for r in long_rows if r[3] == "NO")
    print(
        f"\nfunctions over {args.max_lines} lines: {len(long_rows)} "
        f"({missing} without a '{REASON_MARK}' reason comment)"
    )
    if long_rows:
        print(table(long_rows, ("where", "function", "lines", "reason")))

    graph = {
        n: import_edges(n, modules[n].name == "__init__.py", trees[n], set(modules))
        for n in modules
    }
    unplaced = sorted({part_of(n) for n in modules} - set(layer_index()))
    if unplaced:
        print(f"\nparts in no layer of LAYERS: {', '.join(repr(p) for p in unplaced)}")
    print(
        "\nlayers, lowest first: "
        + " -> ".join("/".join(p or "__init__" for p in parts) for _, parts in LAYERS)
    )
    short = package.name + "."
    upward = upward_imports(graph)
    print(f"upward imports: {len(upward)}")
    for module, target, low, high in upward:
        print(f"  {module.removeprefix(short)} ({low}) -> {target.removeprefix(short)} ({high})")

    groups = strongly_connected(graph)
    cycles = [c for g in groups for c in simple_cycles(graph, g, MAX_CYCLES_PER_GROUP)]
    print(f"import cycles: {len(cycles)} in {len(groups)} group(s) of modules importing each other")
    for group in groups:
        print(f"  group: {', '.join(m.removeprefix(short) for m in group)}")
        found = simple_cycles(graph, group, MAX_CYCLES_PER_GROUP)
        for cycle in found:
            print("    " + " -> ".join(m.removeprefix(short) for m in cycle))
        if len(found) == MAX_CYCLES_PER_GROUP:
            print(f"    ... (first {MAX_CYCLES_PER_GROUP} cycles shown)")

    parts = part_graph(graph)
    part_groups = strongly_connected(parts)
    part_cycles = [c for g in part_groups for c in simple_cycles(parts, g, MAX_CYCLES_PER_GROUP)]
    print(f"cycles between parts: {len(part_cycles)}")
    for cycle in part_cycles:
        print("  " + " -> ".join(p or "__init__" for p in cycle))
    if args.sizes:
        print(
            f"size limits: {over} module(s) over {MODULE_LIMIT} lines, "
            f"{len(long_rows)} function(s) over {args.max_lines} lines"
        )
    oversized = args.sizes and (over or long_rows)
    return 1 if upward or groups or part_groups or unplaced or oversized else 0


if __name__ == "__main__":
    sys.exit(main())
