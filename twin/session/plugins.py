"""Which hooks a ``twin drive`` session gets, from its CLI options, imported only when used.

Each plugin names a factory as ``"package.module:attribute"``; the attribute is called with one argument,
a read-only mapping of all drive options (``udm``, ``udm_every``, ``udm_bbox``, ``record``, ``traffic``,
``pedestrians``, ``demand``, ``seed``, ``dt``, ``duration``, ...), and returns a ``SessionHook``.
A class whose ``__init__(self, options)`` takes that mapping is a factory too.
"""

from __future__ import annotations

import importlib
import logging
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

from tavf_mapkit.errors import InputError
from twin.session.hooks import SessionHook

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Plugin:
    name: str
    target: str
    wanted: Callable[[Mapping[str, Any]], bool]
    # ``record`` is on by default but only when its module exists; an explicit request must not be dropped.
    optional_when_default: bool = False


def _record_wanted(options: Mapping[str, Any]) -> bool:
    return options.get("record") is not False


PLUGINS: tuple[Plugin, ...] = (
    Plugin("traffic", "twin.traffic.hook:TrafficHook",
           lambda o: bool(o.get("traffic")) or bool(o.get("pedestrians")) or bool(o.get("demand"))),
    Plugin("udm", "twin.udm.loop:UdmHook", lambda o: bool(o.get("udm"))),
    # Recording goes last so it sees what the other hooks added to a frame's step.
    Plugin("record", "twin.recording.hook:RecordingHook", _record_wanted, optional_when_default=True),
)


def load_target(target: str) -> Callable[..., Any]:
    module_name, attribute = target.split(":")
    return getattr(importlib.import_module(module_name), attribute)


def create_hooks(options: Mapping[str, Any], plugins: tuple[Plugin, ...] = PLUGINS) -> list[SessionHook]:
    """Hooks for these options, in plugin order. A wanted plugin that cannot be imported is an InputError,
    except an optional default (``record`` without ``--record``), which is skipped with a log line."""
    frozen = MappingProxyType(dict(options))
    hooks: list[SessionHook] = []
    for plugin in plugins:
        if not plugin.wanted(frozen):
            continue
        try:
            factory = load_target(plugin.target)
        except (ImportError, AttributeError) as error:
            if plugin.optional_when_default and frozen.get(plugin.name) is None:
                log.info("%s hook not available (%s); skipped", plugin.name, error)
                continue
            raise InputError(f"--{plugin.name} is not available: {error}") from None
        hooks.append(factory(frozen))
    return hooks
