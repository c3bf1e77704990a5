"""Names for the things a user plugs in: policies, detectors and scenarios.

A name resolves, in this order, to
1. a built-in entry of the catalogue ("module:attr", imported only when asked for, so no package imports
   the code of a floor above it);
2. an entry point of an installed package, in the catalogue's group (`ftcgym.policies`,
   `ftcgym.detectors`, `ftcgym.scenarios`), e.g. in the package's pyproject.toml:
   `[project.entry-points."ftcgym.policies"] my-policy = "mypkg.policies:MyPolicy"`;
3. a "MODULE:ATTR" reference to an importable module, e.g. `mypkg.policies:MyPolicy`.

Anything else is a ValueError that says what was tried and what is accepted. An entry point named like a
built-in cannot replace it: it is left out, with a `PluginNameWarning`.
"""
from __future__ import annotations

import difflib
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from importlib import import_module, metadata


@dataclass(frozen=True)
class Entry:
    """A built-in catalogue entry: where the object lives and one line on what it is."""

    target: str                 # "module:attr"
    description: str = ""


class PluginNameWarning(UserWarning):
    """An installed plug-in's entry point has the name of a built-in, which keeps it."""


class Registry:
    """The catalogue of one kind of plug-in (see the module docstring). `reserved`, if given, returns further
    names that come before the entry points (the scenarios registered in this process)."""

    def __init__(self, kind: str, group: str, builtins: dict[str, Entry],
                 reserved: Callable[[], object] | None = None):
        self.kind, self.group, self.builtins = kind, group, dict(builtins)
        self._reserved = reserved or (lambda: ())

    def installed(self) -> dict[str, metadata.EntryPoint]:
        """Entry points of installed packages in this catalogue's group, by name; one named like a built-in is
        left out, with a PluginNameWarning."""
        taken = set(self.builtins) | set(self._reserved())
        found = {}
        for ep in metadata.entry_points(group=self.group):
            if ep.name in taken:
                warnings.warn(f"{self.kind}: the entry point {ep.name!r} ({ep.value}) of group {self.group!r} has "
                              f"the name of a built-in or registered {self.kind}, which keeps the name; give it "
                              f"another",
                              PluginNameWarning, stacklevel=2)
            else:
                found[ep.name] = ep
        return found

    def names(self) -> list[str]:
        """Built-in names, then installed ones."""
        return list(self.builtins) + list(self.installed())

    def __iter__(self):
        return iter(self.names())

    def __contains__(self, name) -> bool:
        return name in self.names()

    def describe(self, name: str) -> str:
        entry = self.builtins.get(name)
        return entry.description if entry else f"installed plug-in ({self.installed()[name].value})"

    def load(self, name: str):
        """The object `name` stands for; ValueError naming what was tried and what is accepted."""
        if not isinstance(name, str) or not name:
            raise ValueError(f"{self.kind}: expected a name or MODULE:ATTR, got {name!r}")
        if name in self.builtins:
            return load_reference(self.builtins[name].target, self.kind)
        installed = self.installed()
        if name in installed:
            try:
                return installed[name].load()
            except Exception as error:  # noqa: BLE001 - a plug-in's own failure, reported in one line
                raise ValueError(f"{self.kind} {name!r}: the entry point {installed[name].value!r} of group "
                                 f"{self.group!r} could not be loaded ({type(error).__name__}: {error})") from error
        if ":" in name:
            return load_reference(name, self.kind)
        raise self.unknown(name)

    def unknown(self, name: str, known=()) -> ValueError:
        """The error for `name`, which is none of `known` (names of the caller's own), the built-ins and the
        installed ones: it names the closest of them all and lists them."""
        names = list(known) + [other for other in self.names() if other not in known]
        close = difflib.get_close_matches(name, names, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        return ValueError(f"{self.kind}: unknown name {name!r}{hint}; tried the built-in names and the entry points "
                          f"of group {self.group!r}; accepted: {names} or MODULE:ATTR (an importable module and "
                          f"an attribute of it)")


def load_reference(reference: str, kind: str):
    """The attribute ATTR of module MODULE for "MODULE:ATTR" (ATTR may be dotted: "mod:Class.factory")."""
    module_name, _, attribute = reference.partition(":")
    if not module_name or not attribute:
        raise ValueError(f"{kind}: {reference!r} is not of the form MODULE:ATTR")
    try:
        target = import_module(module_name)
    except ImportError as error:
        raise ValueError(f"{kind}: {reference!r}: module {module_name!r} could not be imported ({error}); "
                         f"is it on PYTHONPATH or installed?") from None
    except Exception as error:  # noqa: BLE001 - the module's own failure, reported in one line
        raise ValueError(f"{kind}: {reference!r}: importing module {module_name!r} raised {type(error).__name__}: "
                         f"{error} (python -c 'import {module_name}' shows where)") from error
    for part in attribute.split("."):
        if not hasattr(target, part):
            raise ValueError(f"{kind}: {reference!r}: module {module_name!r} has no attribute {attribute!r}")
        target = getattr(target, part)
    return target
