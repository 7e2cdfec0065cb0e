"""The Stage interface and the registry that lets a stage plug in without touching the runner.

A stage is a class with a name, the artifacts it reads, the options that change its result, and
``run(context) -> StageOutput``. Decorate it with ``@register_stage("name")`` in a module under
``tavf_mapkit/pipeline/builtin/``; the runner finds it by name when a pipeline lists it::

    @register_stage("mesh")
    class MeshStage(Stage):
        inputs = ("xodr",)
        def options(self, context):
            return {"eps": context.section("mesh").get("eps", 0.05)}
        def run(self, context):
            path = context.output_path("mesh/road.glb")
            ...
            return StageOutput(files={"mesh": "mesh"}, facts={"triangles": n})

Rules the runner relies on:
- A stage writes only inside ``context.folder`` and only new files; it never changes a file that an
  earlier stage wrote in place (write a new file and rename it), because reused outputs are copies of
  the previous build and in-place edits would be lost on the next incremental run.
- The result depends only on the inputs' content and ``options()``; bump ``version`` when the code
  changes what it writes, so builds made by the old code are not reused.
- ``facts`` are small, deterministic JSON values (counts, georeference, warning summaries), not timings.
- A stage that declares ``makes`` (the artifact names its StageOutput may hold) lets a later stage with
  ``runs_beside`` start in a process of its own while it runs, when it makes none of that stage's inputs
  (pipeline/beside.py). Such a stage reads only its inputs and the facts of the stages before them, writes only
  its own files, and is a module-level class (its child process imports it by name).
"""

from __future__ import annotations

import importlib
import pkgutil
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, ClassVar

if TYPE_CHECKING:
    from tavf_mapkit.pipeline.context import BuildContext

DEFAULT_STAGES = ("extract", "netconvert", "opendrive", "mesh", "collision", "check", "report")
BUILTIN_PACKAGE = "tavf_mapkit.pipeline.builtin"

_REGISTRY: dict[str, Stage] = {}
_UNAVAILABLE: dict[str, str] = {}  # module name -> why it could not be imported
_discovered = False


@dataclass
class StageOutput:
    """What a stage produced: ``files`` maps artifact names to paths relative to the build folder."""

    files: dict[str, str] = field(default_factory=dict)
    facts: dict = field(default_factory=dict)


class Stage:
    """Base class of pipeline stages (see the module docstring for the contract)."""

    name: ClassVar[str] = ""
    inputs: ClassVar[tuple[str, ...]] = ()           # artifacts that must exist before it can run
    optional_inputs: ClassVar[tuple[str, ...]] = ()  # artifacts it uses when an earlier stage made them
    # the kinds of build input it works on (runner.INPUT_KINDS); for others the runner skips it with a note
    input_kinds: ClassVar[tuple[str, ...]] = ("osm", "sumo-net", "opendrive")
    version: ClassVar[str] = "1"
    description: ClassVar[str] = ""
    #: the artifacts it may make (its StageOutput.files' keys); None: not declared, so no later stage starts
    #: beside it
    makes: ClassVar[tuple[str, ...] | None] = None
    #: it may run in a process of its own beside the stages before it once its inputs exist (pipeline/beside.py)
    runs_beside: ClassVar[bool] = False

    def options(self, context: BuildContext) -> dict:
        """The options that change this stage's result (part of its fingerprint and of manifest.json)."""
        return {}

    def run(self, context: BuildContext) -> StageOutput:
        raise NotImplementedError


def register_stage(name: str):
    """Class decorator: make the stage available to pipelines under ``name`` (replacing an earlier one)."""

    def decorate(cls: type[Stage]) -> type[Stage]:
        cls.name = name
        _REGISTRY[name] = cls()
        return cls

    return decorate


def unregister_stage(name: str) -> None:
    """Remove a stage (tests register temporary stages and clean up after themselves)."""
    _REGISTRY.pop(name, None)


def get_stage(name: str) -> Stage | None:
    """The registered stage called ``name``, or None if no module provides it."""
    discover_stages()
    return _REGISTRY.get(name)


def registered_stages() -> dict[str, Stage]:
    discover_stages()
    return dict(_REGISTRY)


def unavailable_modules() -> dict[str, str]:
    """Stage modules that failed to import, with the reason (shown in the note of a missing stage)."""
    discover_stages()
    return dict(_UNAVAILABLE)


def discover_stages() -> None:
    """Import every module of the builtin package once; each registers its stages as it is imported.

    A module that fails to import (a missing optional dependency) makes only its own stages unavailable.
    """
    global _discovered
    if _discovered:
        return
    _discovered = True
    package = importlib.import_module(BUILTIN_PACKAGE)
    for module in pkgutil.iter_modules(package.__path__, f"{BUILTIN_PACKAGE}."):
        try:
            importlib.import_module(module.name)
        except ImportError as error:
            _UNAVAILABLE[module.name.rsplit(".", 1)[-1]] = str(error)
