"""Plugin discovery through entry points.

Each plugin is a frozen :class:`PluginSpec` object exposed under one of the entry-point groups
in :data:`GROUPS`. Spec modules must stay light (pydantic config + a factory that imports the
heavy implementation lazily), so listing plugins imports no torch-heavy backend code, and using
one plugin imports only that plugin's implementation.

During development, ``L2CALIB_PLUGINS`` registers extra plugins without packaging::

    L2CALIB_PLUGINS="l2calib.backends:my-lio=my_pkg.spec:SPEC;l2calib.references:x=mod:OBJ"

Built-in plugins register through the same entry points from their own distributions
(``l2calib`` for references, ``l2calib-backends``, ``l2calib-policies``).
"""

from __future__ import annotations

import importlib
import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from importlib import metadata
from typing import Any

from pydantic import BaseModel

from l2calib.errors import PluginError

GROUPS = ("l2calib.backends", "l2calib.references", "l2calib.policies")
ENV_VAR = "L2CALIB_PLUGINS"

#: Built-in plugin names and the distribution that ships them, for "not installed" hints.
KNOWN_PLUGINS: dict[tuple[str, str], str] = {
    ("l2calib.backends", "iekf"): "l2calib-backends",
    ("l2calib.backends", "gtsam"): "l2calib-backends",
    ("l2calib.backends", "vio"): "l2calib-backends",
    ("l2calib.references", "kiss-icp"): "l2calib",
    ("l2calib.references", "ct-lidar"): "l2calib",
    ("l2calib.references", "gt-file"): "l2calib",
    ("l2calib.references", "rtk"): "l2calib",
    ("l2calib.policies", "bingham"): "l2calib-policies",
    ("l2calib.policies", "gaussian"): "l2calib-policies",
}


@dataclass(frozen=True)
class PluginSpec:
    """What a plugin declares about itself.

    Attributes:
        name: Name used in recipes (``backend.name: iekf``).
        group: Entry-point group, one of :data:`GROUPS`.
        config: Pydantic model of the plugin's options (``backend.options`` in a recipe).
        factory: ``factory(config, **context) -> instance``; imports heavy code lazily.
        description: One line shown by ``l2calib plugins``.
        evaluation: Backends only: the options that make the backend the continuous odometry
            ``l2calib evaluate`` runs with a given extrinsic (merged over the recipe's
            ``backend.options``); empty: the recipe's options as they are.
    """

    name: str
    group: str
    config: type[BaseModel]
    factory: Callable[..., Any]
    description: str
    evaluation: dict[str, Any] = field(default_factory=dict)

    def build(self, options: BaseModel | dict[str, Any] | None = None, **context: Any) -> Any:
        """Validates ``options`` against :attr:`config` and calls the factory."""
        cfg = options if isinstance(options, self.config) else self.config(**(options or {}))
        return self.factory(cfg, **context)


@dataclass(frozen=True)
class EntryPointLike:
    """Minimal entry-point record (what :class:`importlib.metadata.EntryPoint` provides)."""

    name: str
    group: str
    value: str
    dist_name: str | None = None
    loader: Callable[[], Any] | None = field(default=None, compare=False)

    def load(self) -> Any:
        """Imports the object ``module:attr`` named by :attr:`value` (or calls ``loader``)."""
        if self.loader is not None:
            return self.loader()
        module, _, attr = self.value.partition(":")
        obj: Any = importlib.import_module(module)
        for part in filter(None, attr.split(".")):
            obj = getattr(obj, part)
        return obj


EntryPointSource = Callable[[str], Iterable[EntryPointLike]]


def installed_entry_points(group: str) -> list[EntryPointLike]:
    """Entry points of ``group`` from installed distributions plus :data:`ENV_VAR`."""
    found = [
        EntryPointLike(ep.name, group, ep.value, ep.dist.name if ep.dist else None)
        for ep in metadata.entry_points(group=group)
    ]
    return found + env_entry_points(group)


def env_entry_points(group: str, env: str | None = None) -> list[EntryPointLike]:
    """Parses :data:`ENV_VAR` (``group:name=module:attr`` items separated by ``;``)."""
    text = os.environ.get(ENV_VAR, "") if env is None else env
    out = []
    for item in filter(None, (s.strip() for s in text.split(";"))):
        head, sep, value = item.partition("=")
        grp, colon, name = head.partition(":")
        if not sep or not colon or ":" not in value:
            raise PluginError(
                f"{ENV_VAR} item {item!r} is malformed",
                fix="write items as group:name=module:attribute separated by ';'",
            )
        if grp == group:
            out.append(EntryPointLike(name.strip(), grp, value.strip(), f"${ENV_VAR}"))
    return out


class PluginRegistry:
    """Finds, type-checks and loads plugins; the entry-point source is swappable for tests."""

    def __init__(self, source: EntryPointSource = installed_entry_points) -> None:
        self._source = source

    def _entries(self, group: str) -> dict[str, list[EntryPointLike]]:
        if group not in GROUPS:
            raise PluginError(f"unknown plugin group {group!r}", fix=f"use one of {GROUPS}")
        by_name: dict[str, list[EntryPointLike]] = {}
        for ep in self._source(group):
            by_name.setdefault(ep.name, []).append(ep)
        return by_name

    @staticmethod
    def _check_unique(group: str, name: str, eps: list[EntryPointLike]) -> EntryPointLike:
        if len(eps) > 1:
            where = ", ".join(f"{e.value} ({e.dist_name or 'unknown distribution'})" for e in eps)
            raise PluginError(
                f"plugin name {name!r} is registered {len(eps)} times in {group}: {where}",
                fix="uninstall one of the distributions or rename one plugin",
            )
        return eps[0]

    @staticmethod
    def _load(group: str, ep: EntryPointLike) -> PluginSpec:
        try:
            obj = ep.load()
        except Exception as exc:  # an import failure inside a plugin is the plugin's problem
            raise PluginError(
                f"plugin {ep.name!r} in {group} ({ep.value}) failed to import: {exc}",
                fix=f"reinstall {ep.dist_name or 'the plugin distribution'}",
            ) from exc
        if not isinstance(obj, PluginSpec):
            raise PluginError(
                f"entry point {ep.name!r} in {group} ({ep.value}) is a "
                f"{type(obj).__name__}, not a PluginSpec",
                fix="point the entry point at a l2calib.plugins.PluginSpec object",
            )
        if obj.name != ep.name or obj.group != group:
            raise PluginError(
                f"entry point {ep.name!r} in {group} loads spec {obj.name!r} of group "
                f"{obj.group!r}",
                fix="make the entry-point name and group match the spec",
            )
        if not (isinstance(obj.config, type) and issubclass(obj.config, BaseModel)):
            raise PluginError(f"plugin {ep.name!r}: config must be a pydantic model class")
        return obj

    def names(self, group: str) -> list[str]:
        """Sorted plugin names of ``group`` (without importing them)."""
        return sorted(self._entries(group))

    def get(self, group: str, name: str) -> PluginSpec:
        """Loads one plugin's spec, importing only that plugin's spec module."""
        entries = self._entries(group)
        if name not in entries:
            dist = KNOWN_PLUGINS.get((group, name))
            available = ", ".join(sorted(entries)) or "none"
            if dist:
                raise PluginError(
                    f"plugin {name!r} ({group}) is not installed",
                    fix=f"install the {dist} distribution (from the repo: pip install -e "
                    f"{'.' if dist == 'l2calib' else dist.split('-', 1)[1]})",
                )
            raise PluginError(
                f"no plugin named {name!r} in {group}", fix=f"use one of: {available}"
            )
        return self._load(group, self._check_unique(group, name, entries[name]))

    def discover(self, group: str) -> dict[str, tuple[PluginSpec, str | None]]:
        """Loads every plugin of ``group``: name -> (spec, distribution name)."""
        out = {}
        for name, eps in sorted(self._entries(group).items()):
            ep = self._check_unique(group, name, eps)
            out[name] = (self._load(group, ep), ep.dist_name)
        return out


_default_registry = PluginRegistry()


def get_plugin(group: str, name: str) -> PluginSpec:
    """Loads one plugin spec from the installed registry (see :meth:`PluginRegistry.get`)."""
    return _default_registry.get(group, name)


def discover(group: str) -> dict[str, tuple[PluginSpec, str | None]]:
    """All plugins of ``group`` from the installed registry."""
    return _default_registry.discover(group)
