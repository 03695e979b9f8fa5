"""Finders that run code around the import of one package: tap-bench registers its Gymnasium
ids when Gymnasium is imported (:mod:`tap_bench.sim.registration`) and imports highway-env
without matplotlib (:mod:`tap_bench.sim`).

:class:`AroundImport` finds the package's real spec with the other finders and puts itself
in as its loader, so that a subclass's ``exec_module`` runs the real loader with its own code
around it and then steps aside (:meth:`AroundImport.step_aside`).

Neither hook ever changes the list ``sys.meta_path`` in place: an import walks that list while
the hooked import may finish (in another thread, or in a finder further down), and a finder
removed before the walk's position would make it skip the next one (the module it would have
found is then missing). A hook steps aside by putting a new list in its place, and asks the
other finders for the real package with a flag set (the import system calls finders under
its lock).
"""

from __future__ import annotations

import importlib.abc
import importlib.util
import sys
import types
from collections.abc import Callable
from typing import Any, ClassVar

__all__ = ["AroundImport", "ImportRecorder"]


class AroundImport(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """A finder and loader for the module named :attr:`target` (see the module docstring);
    subclasses add :meth:`wanted` conditions and their ``exec_module``."""

    target: ClassVar[str] = ""
    _finding = False

    def wanted(self) -> bool:
        """Whether to stand in for this import (default: always)."""
        return True

    def find_spec(self, name: str, path: Any = None, target: Any = None) -> Any:
        if name != self.target or self._finding or not self.wanted():
            return None
        self._finding = True  # the real package, as the other finders find it
        try:
            spec = importlib.util.find_spec(name)
        finally:
            self._finding = False
        if spec is None or spec.loader is None:
            return None
        self.real = spec.loader
        spec.loader = self
        return spec

    def create_module(self, spec: Any) -> Any:
        return self.real.create_module(spec)

    def leave_meta_path(self) -> None:
        """Take this finder out of ``sys.meta_path`` (a new list, never the list in place)."""
        sys.meta_path = [f for f in sys.meta_path if f is not self]

    def step_aside(self, module: types.ModuleType) -> None:
        """Give ``module`` its own loader back (``pkgutil.get_data``,
        ``importlib.resources.files`` ask it) and leave ``sys.meta_path``."""
        module.__loader__ = module.__spec__.loader = self.real
        self.leave_meta_path()


class ImportRecorder(importlib.abc.MetaPathFinder):
    """A finder that finds nothing and tells ``note`` the name of every module the process
    imports for the first time while it is first in ``sys.meta_path``: what a policy or a
    measure loads by name as it runs (``importlib.import_module("helper")``), which no
    import statement shows (:func:`tap_bench.usercode.recording`)."""

    def __init__(self, note: Callable[[str], None]) -> None:
        self.note = note

    def find_spec(self, name: str, path: Any = None, target: Any = None) -> None:
        self.note(name)
        return None

    def install(self) -> None:
        """Put this finder first in ``sys.meta_path`` (a new list), once."""
        if not sys.meta_path or sys.meta_path[0] is not self:
            sys.meta_path = [self, *(f for f in sys.meta_path if f is not self)]
