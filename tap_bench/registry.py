"""One small registry class for everything users add: measures, data formats, policy kinds.

A :class:`Registry` holds named entries in registration order. It refuses a name registered
twice (a second registration is a mistake, never a silent override: waymax's
``register_metric`` does the same) and answers a missing name with "did you mean ...?"
(Gymnasium's ``make``). An optional ``check`` runs on every entry before it is added, so a
registry holds only entries that work.

The registries built on it:

- :data:`tap_bench.bench.measures.MEASURES`: the ego's safety and efficiency measures;
- :data:`tap_bench.sources.registry.READERS`: the driving-data formats;
- :data:`tap_bench.sim.policies.POLICY_KINDS`: the ``kind`` a policy file can name.

Entries exist in the process that registered them. To have them in every process of a run
(worker processes, Ray workers), name the modules that register them as plugins
(:mod:`tap_bench.plugins`): ``--plugin MODULE`` on the command line, ``"plugins"`` in a suite.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Generic, TypeVar

from tap_bench.errors import RegistrationError, did_you_mean

__all__ = ["Registry"]

E = TypeVar("E")


class Registry(Generic[E]):
    """Named entries in registration order; refuses duplicates, did-you-mean on a miss.

    Args:
        what: what an entry is, for messages (``"measure"``, ``"format"``).
        check: run on an entry before it is added; raises
            :class:`~tap_bench.errors.RegistrationError` to refuse it.
        name: the entry's name (default: its ``name`` attribute).
    """

    def __init__(self, what: str, *, check: Callable[[E], None] | None = None,
                 name: Callable[[E], str] | None = None) -> None:
        self.what = what
        self._check = check
        self._name = name or _entry_name
        self._entries: dict[str, E] = {}

    def register(self, entry: E) -> E:
        """Add ``entry`` and return it.

        Raises:
            RegistrationError: its name is taken, or ``check`` refuses it.
        """
        name = self._name(entry)
        if name in self._entries:
            raise RegistrationError(f"a {self.what} named {name!r} is already registered; pick "
                                    f"another name (a {self.what} is registered once).")
        if self._check is not None:
            self._check(entry)
        self._entries[name] = entry
        return entry

    def unregister(self, name: str) -> None:
        """Remove an entry (for tests, and plug-ins that replace their own)."""
        del self._entries[self._name(self[name])]

    def __getitem__(self, name: str) -> E:
        try:
            return self._entries[name]
        except KeyError:
            raise did_you_mean(self.what, name, self._entries) from None

    def get(self, name: str, default: E | None = None) -> E | None:
        """The entry named ``name``, or ``default``."""
        return self._entries.get(name, default)

    def __contains__(self, name: object) -> bool:
        return name in self._entries

    def __iter__(self) -> Iterator[E]:
        return iter(tuple(self._entries.values()))

    def __len__(self) -> int:
        return len(self._entries)

    def names(self) -> tuple[str, ...]:
        """The entries' names, in registration order."""
        return tuple(self._entries)

    def __repr__(self) -> str:
        return f"Registry({self.what!r}: {', '.join(self._entries) or 'empty'})"


def _entry_name(entry: object) -> str:
    return str(entry.name)  # type: ignore[attr-defined]
