"""How much of each tap-bench module re-states highway-env's or Stable-Baselines3's code.

For every module of ``tap_bench/sim`` and ``tap_bench/rl`` (``--all``: every module of
``tap_bench``), the share of its statements that match statements of the installed
``highway_env`` and ``stable_baselines3`` packages (their source in site-packages;
``--upstream`` names other packages) once identifiers and literals are renamed, and the
longest matching runs with both places.

What counts, exactly
--------------------
*Statements.* A module's statements are its simple statements and the headers of its
compound statements (``def``, ``class``, ``if``, ``for``, ``while``, ``with``, ``try``,
each ``except`` clause, ``match`` and each ``case``), in source order (a pre-order walk:
a header, then its body, then its ``else``/``finally`` part). Left out and not counted:
bare string expressions (docstrings), ``import`` and ``from ... import``, ``pass``,
``global``/``nonlocal`` and annotation-only declarations (``x: int``, dataclass fields).

*Normalised shape of a statement.* Its syntax tree (a compound statement's header only,
without its body) with

- every identifier replaced by a slot numbered by first appearance within the statement:
  names, function and class names and parameters in one namespace, attribute names and
  keyword-argument names in a second one (``self.a = a + b`` and ``v.x = x + y`` have one
  shape, ``v.x = y + z`` another);
- every literal replaced by one placeholder (numbers, strings, f-strings, bytes, ``None``,
  ``True``, ``False``: ``1 / 2`` and ``0.5`` stay different, ``2`` and ``3.5`` do not);
- type annotations dropped (``x: float = v`` is ``x = v``; parameter and return
  annotations are gone);
- node kinds, operators, the order and number of arguments kept. Nesting is not part of
  the shape (``elif`` and a second ``if`` have one shape), so that a loop body turned into
  a function body still pairs.

*Runs.* A pair is a tap-bench statement and an upstream statement of the same shape. A run
is a chain of pairs with one upstream module, in the same order on both sides, skipping at
most ``--gap`` (G, default 4) statements on either side between two pairs (a copy with a
few statements edited, inserted or left out is still one run; with G = 0 only consecutive
statements, the ``consecutive`` column). A run counts when it has at least ``--min-pairs``
(default 4) pairs and its *distinctive* pairs hold at least ``--min-nodes`` (default 24)
syntax-tree nodes in all: a shape found more than ``--common`` (default 30) times in the
upstream packages (``self.x = y``, ``return x``, ``if x is None:``, ``x = C``) is an idiom,
paired but not weighed, so runs of idioms (an ``__init__`` storing its parameters, class
constants) never count. Each pair extends the chain before it with the most such nodes.

*Share.* A statement matches when it is a pair of a counted run; a module's share =
matching statements / statements. The runs are printed longest first, with the tap-bench
lines and the upstream lines.

What it cannot see: statements whose calls were rewritten (a method call turned into a
function call, keyword arguments into positional ones) or that were merged, split or
reordered do not pair (the gap lets a run pass over a few of them); a loop over vehicles
re-written as numpy array operations is, by construction, not a match. It measures
re-stated text, not borrowed ideas; reading is still needed for what it flags.

Calibration (highway-env 1.12.1, SB3 2.9.2, tap-bench main of 2026-12-01): over the
~14,000 statements of tap-bench outside ``sim/`` and ``rl/`` (code never derived from
either package) one run of 4 pairs counts (``bench/report/figures.py``'s SVG writer against
SB3's CSV logger: ``self.parts.append(f"...")`` against ``self.file.write(...)``), while
``rl/vec_env.py``'s restated ``_worker`` loop (``send`` turned into ``return``, ``elif``
into ``if``) is one run of 27 pairs. Per-statement matching without runs is no measure:
70 % of ``tableio.py``'s statements have a shape found somewhere upstream.

Usage::

    python benchmarks/upstream_match.py [--root CHECKOUT] [--all] [--gap 4]
        [--min-pairs 4] [--min-nodes 24] [--common 30] [--top 3]
        [--upstream highway_env,stable_baselines3]

Prints the table and writes it with the machine (``benchmarks/out/upstream_match.json``).
"""

from __future__ import annotations

import argparse
import ast
import importlib.util
import sys
from dataclasses import dataclass, field
from pathlib import Path

from machine import ROOT, report

SKIPPED = (ast.Import, ast.ImportFrom, ast.Pass, ast.Global, ast.Nonlocal)
"""Statements neither counted nor compared."""

BODIES = ("body", "handlers", "orelse", "finalbody", "cases")
"""The fields of a compound statement that hold statements (walked after its header)."""

NOT_SHAPE = frozenset({"ctx", "type_comment", "annotation", "returns", "type_params",
                       *BODIES})
"""Fields left out of a statement's shape."""


@dataclass
class Statement:
    """One statement of a walk: its shape template (strings, and ``(namespace,
    identifier)`` slots), its syntax-tree node count and its first and last lines."""

    template: list
    nodes: int
    line: int
    end_line: int


@dataclass
class Module:
    """A module's statements in walk order; ``path``: how it is printed."""

    path: str
    statements: list[Statement] = field(default_factory=list)


def _template(node: ast.AST, out: list) -> int:
    """Append ``node``'s normalised shape to ``out``; return its node count."""
    if isinstance(node, ast.Name):
        out.append(("n", node.id))
        return 1
    if isinstance(node, ast.arg):
        out.append(("n", node.arg))
        return 1
    if isinstance(node, (ast.Constant, ast.JoinedStr)):
        out.append("C")
        return 1
    if isinstance(node, ast.Attribute):
        out.append("Attr(")
        count = 1 + _template(node.value, out)
        out.append(("a", node.attr))
        out.append(")")
        return count
    if isinstance(node, ast.keyword):
        out.append("kw(")
        out.append(("a", node.arg) if node.arg is not None else "**")
        count = 1 + _template(node.value, out)
        out.append(")")
        return count
    if isinstance(node, ast.AnnAssign):  # x: T = v  ->  x = v
        out.append("Assign(")
        count = 1 + _template(node.target, out) + _template(node.value, out)
        out.append(")")
        return count
    out.append(type(node).__name__ + "(")
    count = 1
    if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
        out.append(("n", node.name))
    for name, value in ast.iter_fields(node):
        if name in NOT_SHAPE or (name == "name" and isinstance(
                node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef))):
            continue
        if isinstance(value, list):
            out.append("[")
            for item in value:
                if isinstance(item, ast.AST):
                    count += _template(item, out)
                elif item is None:  # kw_defaults' missing defaults
                    out.append("-")
                else:
                    out.append(repr(item))
            out.append("]")
        elif isinstance(value, ast.AST):
            count += _template(value, out)
        elif name == "name" and isinstance(value, str):  # except ... as name, MatchAs
            out.append(("n", value))
        elif value is None:
            out.append("-")
        else:
            out.append(repr(value))
    out.append(")")
    return count


def _walk(body: list[ast.stmt], out: list[Statement]) -> None:
    """Append the statements of ``body``, and those of their bodies, to ``out``."""
    for stmt in body:
        if isinstance(stmt, SKIPPED) or (
                isinstance(stmt, ast.Expr) and isinstance(stmt.value, ast.Constant)
                and isinstance(stmt.value.value, str)) or (
                isinstance(stmt, ast.AnnAssign) and stmt.value is None):
            continue
        template: list = []
        nodes = _template(stmt, template)
        compound = any(isinstance(getattr(stmt, f, None), list) and getattr(stmt, f)
                       for f in BODIES)
        end = stmt.lineno if compound else (stmt.end_lineno or stmt.lineno)
        out.append(Statement(template, nodes, stmt.lineno, end))
        for part in BODIES:
            children = getattr(stmt, part, None)
            if not children:
                continue
            if part in ("handlers", "cases"):
                for child in children:
                    template = []
                    nodes = _template(child, template)
                    line = getattr(child, "lineno", None) or getattr(child.pattern, "lineno", 0)
                    out.append(Statement(template, nodes, line, line))
                    _walk(child.body, out)
            else:
                _walk(children, out)


def read_module(path: Path, shown: str) -> Module | None:
    """The statements of the module at ``path`` (None when it does not parse)."""
    try:
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    except (SyntaxError, UnicodeDecodeError, ValueError):
        return None
    module = Module(shown)
    _walk(tree.body, module.statements)
    return module


def statement_key(stmt: Statement) -> str:
    """The statement's normalised shape: its template with the slots numbered by first
    appearance within the statement."""
    slots: dict[str, dict[str, int]] = {"n": {}, "a": {}}
    parts = []
    for token in stmt.template:
        if isinstance(token, tuple):
            names = slots[token[0]]
            parts.append(f"{token[0]}{names.setdefault(token[1], len(names))}")
        else:
            parts.append(token)
    return " ".join(parts)


def package_modules(package: str) -> list[Module]:
    """Every module of the installed ``package``, printed relative to site-packages."""
    spec = importlib.util.find_spec(package)
    if spec is None or not spec.submodule_search_locations:
        raise SystemExit(f"{package} is not installed as a package here: install it, or "
                         "leave it out of --upstream")
    folder = Path(next(iter(spec.submodule_search_locations)))
    return [m for p in sorted(folder.rglob("*.py"))
            if (m := read_module(p, str(p.relative_to(folder.parent)))) is not None]


@dataclass
class Run:
    """A matching run: tap-bench statements ``start`` to ``end`` (indices) against upstream
    module ``other``'s ``other_start`` to ``other_end``; ``pairs`` statements paired, of
    ``nodes`` syntax-tree nodes."""

    start: int
    end: int
    other: int
    other_start: int
    other_end: int
    pairs: int
    nodes: int


def match_module(module: Module, index: dict[str, list[tuple[int, int]]], gap: int,
                 min_pairs: int, min_nodes: int, common: int) -> tuple[set[int], list[Run]]:
    """The indices of ``module``'s matching statements and its runs, most nodes first.

    A run is a chain of pairs (tap-bench statement i, upstream statement j of one module)
    of equal shape, i and j both increasing, at most ``gap`` statements skipped on either
    side between two pairs. It counts with at least ``min_pairs`` pairs whose statements of
    a shape found at most ``common`` times upstream hold ``min_nodes`` nodes or more. Each
    pair extends the chain before it with the most such nodes."""
    stmts = module.statements
    # (i, upstream module, j) -> (pairs, nodes of uncommon shapes, the pair before it)
    chains: dict[tuple[int, int, int], tuple[int, int, tuple | None]] = {}
    extended: set[tuple[int, int, int]] = set()
    for i, stmt in enumerate(stmts):
        places = index.get(statement_key(stmt), ())
        weight = stmt.nodes if len(places) <= common else 0
        for other, j in places:
            best = None
            for di in range(1, gap + 2):
                for dj in range(1, gap + 2):
                    before = (i - di, other, j - dj)
                    found = chains.get(before)
                    if found is not None and (best is None or found[:2] > chains[best][:2]):
                        best = before
            pairs, nodes = chains[best][:2] if best is not None else (0, 0)
            chains[(i, other, j)] = (pairs + 1, nodes + weight, best)
            if best is not None:
                extended.add(best)
    matching: set[int] = set()
    runs = []
    for end, (pairs, nodes, before) in chains.items():
        if end in extended or pairs < min_pairs or nodes < min_nodes:
            continue
        first = end
        while before is not None:
            matching.add(first[0])
            first, before = before, chains[before][2]
        matching.add(first[0])
        runs.append(Run(first[0], end[0], end[1], first[2], end[2], pairs, nodes))
    best_runs: dict[int, Run] = {}
    for run in runs:  # one run per tap-bench start: the one with the most nodes
        kept = best_runs.get(run.start)
        if kept is None or run.nodes > kept.nodes:
            best_runs[run.start] = run
    return matching, sorted(best_runs.values(), key=lambda r: (-r.nodes, -r.pairs, r.start))


def lines(module: Module, start: int, end: int) -> str:
    """``path:first-last`` of statements ``start`` to ``end``."""
    return f"{module.path}:{module.statements[start].line}-{module.statements[end].end_line}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=ROOT,
                        help="the tap-bench checkout to measure (default: this one)")
    parser.add_argument("--all", action="store_true",
                        help="every module of tap_bench, not only sim/ and rl/")
    parser.add_argument("--gap", type=int, default=4,
                        help="statements a run may skip on either side between two pairs")
    parser.add_argument("--min-pairs", type=int, default=4,
                        help="paired statements a run needs to count")
    parser.add_argument("--min-nodes", type=int, default=24,
                        help="syntax-tree nodes a run's paired statements need to count")
    parser.add_argument("--common", type=int, default=30,
                        help="a statement shape found more often upstream is an idiom: its "
                             "nodes do not count towards --min-nodes")
    parser.add_argument("--top", type=int, default=3, help="runs printed per module")
    parser.add_argument("--upstream", default="highway_env,stable_baselines3",
                        help="comma-separated installed packages compared against")
    parser.add_argument("--name", default="upstream_match",
                        help="the JSON written under benchmarks/out/")
    args = parser.parse_args()
    if args.gap < 0 or args.min_pairs < 1 or args.min_nodes < 0:
        parser.error("--gap and --min-nodes must be >= 0, --min-pairs >= 1")
    package = args.root / "tap_bench"
    if not package.is_dir():
        parser.error(f"{args.root} has no tap_bench/ folder: pass a tap-bench checkout")
    upstream = [m for name in args.upstream.split(",") for m in package_modules(name)]
    index: dict[str, list[tuple[int, int]]] = {}
    for number, module in enumerate(upstream):
        for j, stmt in enumerate(module.statements):
            index.setdefault(statement_key(stmt), []).append((number, j))
    paths = sorted(package.rglob("*.py")) if args.all else sorted(
        [*(package / "sim").glob("*.py"), *(package / "rl").glob("*.py")])
    table = {}
    totals = {"statements": 0, "matching": 0, "consecutive": 0}
    for path in paths:
        module = read_module(path, str(path.relative_to(args.root)))
        if module is None or not module.statements:
            continue
        matching, runs = match_module(module, index, args.gap, args.min_pairs,
                                      args.min_nodes, args.common)
        consecutive, _ = match_module(module, index, 0, args.min_pairs, args.min_nodes,
                                      args.common)
        n = len(module.statements)
        row = {"statements": n, "matching": len(matching), "share": round(len(matching) / n, 3),
               "consecutive": len(consecutive),
               "consecutive_share": round(len(consecutive) / n, 3), "runs": [
                   {"tap_bench": lines(module, r.start, r.end), "pairs": r.pairs,
                    "nodes": r.nodes, "upstream": lines(upstream[r.other], r.other_start,
                                                        r.other_end)}
                   for r in runs[:args.top]]}
        table[module.path] = row
        for key in totals:
            totals[key] += n if key == "statements" else row[key]
    width = max((len(p) for p in table), default=10)
    print(f"{'module':<{width}}  statements  matching  share  consecutive (gap 0)")
    for path, row in table.items():
        print(f"{path:<{width}}  {row['statements']:>10}  {row['matching']:>8}  "
              f"{100 * row['share']:>3.0f} %  {row['consecutive']:>6} "
              f"{100 * row['consecutive_share']:>3.0f} %")
        for run in row["runs"]:
            print(f"    {run['pairs']:>3} pairs  {run['tap_bench']}  ~  {run['upstream']}")
    n = max(totals["statements"], 1)
    print(f"{'all':<{width}}  {totals['statements']:>10}  {totals['matching']:>8}  "
          f"{100 * totals['matching'] / n:>3.0f} %  {totals['consecutive']:>6} "
          f"{100 * totals['consecutive'] / n:>3.0f} %", flush=True)
    report(args.name, {"modules": table, **totals}, root=str(args.root), gap=args.gap,
           min_pairs=args.min_pairs, min_nodes=args.min_nodes, common=args.common,
           upstream=args.upstream,
           upstream_modules=len(upstream), upstream_statements=sum(
               len(m.statements) for m in upstream), all_modules=args.all)


if __name__ == "__main__":
    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10_000))
    main()
