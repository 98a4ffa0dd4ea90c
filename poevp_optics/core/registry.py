"""Registries of swappable models keyed by name, each entry citing its source.

After colour-science's `*_METHODS` tables: a stage module owns its registry (`PSFS`,
`MASK_LAWS`, `PREDICTORS`, ...), scene validation takes its choices from it, and adding a model
is one `register` call in one file:

    PSFS.register("lorentzian", build_lorentzian, source="Goodman 2005, Eq. 6-31")
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Iterator


_DECORATE = object()     # `register(name, source=...)` without an object: used as a decorator


class UnknownName(ValueError):
    """A name no entry of the registry carries."""


@dataclass(frozen=True)
class Entry:
    """One registered model: the object (a function, a class, a factory) and its source."""

    name: str
    obj: Any
    source: str
    doc: str = ""


class Registry:
    """Name -> entry, in registration order. `in`, iteration and `len` see the names, so a
    registry is a scene key's `choices`."""

    def __init__(self, what: str):
        self.what = what
        self._entries: dict[str, Entry] = {}

    def register(self, name: str, obj: Any = _DECORATE, *, source: str, doc: str = ""):
        """Register `obj` under `name` (None included: an entry whose rule is elsewhere); without
        `obj`, a decorator that registers what it decorates."""
        if obj is _DECORATE:
            return lambda o: self.register(name, o, source=source, doc=doc)
        if not name or not isinstance(name, str):
            raise ValueError(f"{self.what}: a name must be a non-empty string, got {name!r}")
        if name in self._entries:
            raise ValueError(f"{self.what} {name!r} is already registered")
        self._entries[name] = Entry(name, obj, source, doc)
        return obj

    def unregister(self, name: str) -> None:
        self._entries.pop(name)

    def __getitem__(self, name: str) -> Any:
        try:
            return self._entries[name].obj
        except KeyError:
            raise UnknownName(f"unknown {self.what} {name!r}; known: {', '.join(self._entries)}") from None

    def entry(self, name: str) -> Entry:
        self[name]
        return self._entries[name]

    def __contains__(self, name: object) -> bool:
        return name in self._entries

    def __iter__(self) -> Iterator[str]:
        return iter(list(self._entries))

    def __len__(self) -> int:
        return len(self._entries)

    def names(self) -> tuple[str, ...]:
        return tuple(self._entries)

    def __repr__(self) -> str:
        return f"Registry({self.what!r}: {', '.join(self._entries)})"
