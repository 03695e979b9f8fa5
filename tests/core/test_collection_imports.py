"""Collecting the suite imports no heavy optional library: every pytest worker collects
every test file, so a module-level ``import torch`` (or Stable-Baselines3, or Ray, or a
``pytest.importorskip`` of one) costs each worker its import (torch about 2 CPU s) even
when the worker runs none of that file's tests. Such files import them in their tests
and skip with ``pytestmark = pytest.mark.skipif(importlib.util.find_spec(...) is None)``."""

from __future__ import annotations

import ast
from pathlib import Path

TESTS = Path(__file__).resolve().parents[1]
HEAVY = ("torch", "stable_baselines3", "ray")


def _heavy(name: str | None) -> bool:
    return name is not None and name.split(".")[0] in HEAVY


def module_level_heavy_imports(source: str) -> list[tuple[int, str]]:
    """(line, what) of every import of a :data:`HEAVY` library that runs when the module is
    imported: statements at module level (and in its ``if``/``try`` blocks, not under
    ``if TYPE_CHECKING``), ``pytest.importorskip(...)`` calls among them."""
    found: list[tuple[int, str]] = []

    def visit(body: list[ast.stmt]) -> None:
        for node in body:
            if isinstance(node, ast.Import):
                found.extend((node.lineno, f"import {a.name}") for a in node.names
                             if _heavy(a.name))
            elif isinstance(node, ast.ImportFrom) and _heavy(node.module):
                found.append((node.lineno, f"from {node.module} import ..."))
            elif isinstance(node, ast.If):
                if "TYPE_CHECKING" not in ast.unparse(node.test):
                    visit(node.body)
                visit(node.orelse)
            elif isinstance(node, ast.Try):
                for block in (node.body, node.orelse, node.finalbody,
                              *(h.body for h in node.handlers)):
                    visit(block)
            elif isinstance(node, ast.Expr | ast.Assign):
                for call in ast.walk(node):
                    if (isinstance(call, ast.Call) and "importorskip" in ast.unparse(call.func)
                            and call.args and isinstance(call.args[0], ast.Constant)
                            and _heavy(str(call.args[0].value))):
                        found.append((node.lineno, ast.unparse(call)))

    visit(ast.parse(source).body)
    return found


def test_no_test_module_imports_torch_sb3_or_ray_when_collected():
    offenders = [f"{path.relative_to(TESTS.parent)}:{line}: {what}"
                 for path in sorted(TESTS.rglob("*.py"))
                 for line, what in module_level_heavy_imports(path.read_text(encoding="utf-8"))]
    assert not offenders, ("imported when the suite is collected (import it inside the tests "
                           "that use it):\n" + "\n".join(offenders))


def test_the_check_sees_each_kind_of_module_level_import():
    source = """
import torch
from stable_baselines3.common import vec_env
pytest.importorskip("ray")
ray = pytest.importorskip("ray.util")
try:
    import torch.nn
except ImportError:
    pass
if TYPE_CHECKING:
    import torch
def test_x():
    import torch
import numpy
"""
    assert [line for line, _ in module_level_heavy_imports(source)] == [2, 3, 4, 5, 7]
