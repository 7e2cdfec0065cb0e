"""What a running stage sees: the folder it writes into, the artifacts so far, options and earlier facts."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from tavf_mapkit.pipeline.config import PipelineConfig
from tavf_mapkit.progress import Progress, silent


@dataclass
class BuildContext:
    """Shared state of one build. Artifacts are absolute paths; ``artifacts["input"]`` is the user's file.

    ``input_kind`` is "osm", "sumo-net" or "opendrive". ``facts`` maps a stage name to the facts it reported
    (also for stages reused from the previous build), so a later stage can read ``facts["extract"]["centre"]``.
    ``progress`` is the running stage's: ``report = context.progress("tiles")``, then ``report(done, total)``
    as tiles are finished (tavf_mapkit/progress.py; the command decides whether anyone sees it).
    ``fanout`` is a ``cluster.Fanout`` when the build runs its tile stages on a Dask cluster (``--workers``,
    ``--scheduler``), else None; it never changes what a stage writes.
    """

    name: str
    folder: Path
    input_path: Path
    input_kind: str
    config: PipelineConfig
    artifacts: dict[str, Path] = field(default_factory=dict)
    facts: dict[str, dict] = field(default_factory=dict)
    notify: Callable[[str], None] = lambda message: None
    progress: Progress = silent
    fanout: object | None = None
    #: (file key, map) the mesh stage kept for the check stage (pipeline/builtin/stage_map.py), or None
    kept_map: tuple | None = None
    #: names of the later stages running in processes of their own (pipeline/beside.py), which load what they read
    running_beside: set = field(default_factory=set)

    def section(self, name: str) -> dict:
        """The pipeline file's table ``[name]`` with command-line overrides applied."""
        return self.config.section(name)

    def metres(self, section: str, key: str, default: float) -> float:
        """Option ``[section] key``: a positive, finite number of metres (``default`` when not set).

        Pipeline files are checked on load (schema.py); this guards configurations made in code."""
        from tavf_mapkit.pipeline.schema import check_value, metres

        value = self.section(section).get(key, default)
        check_value(section, key, value, metres())
        return float(value)

    def opendrive(self):
        """The build's OpenDRIVE (artifact ``xodr``) loaded, from its snapshot (artifact ``odrmap``) when that is
        valid (opendrive/snapshot.py); a StageError when it is unreadable."""
        from tavf_mapkit.errors import InputError, StageError
        from tavf_mapkit.opendrive.snapshot import load_build_map

        try:
            return load_build_map(self.artifacts["xodr"], self.artifacts.get("odrmap"))
        except InputError as error:
            if self.input_kind == "opendrive":
                raise  # the user's own map: its defect, named as such (exit 2)
            raise StageError(f"netconvert's OpenDRIVE is unreadable: {error}") from None

    def osm_source(self) -> Path | None:
        """The build's own copy of its OSM input (for buildings), None for a SUMO network input."""
        source = self.artifacts.get("source")
        return source if source is not None and self.input_kind == "osm" else None

    def output_path(self, relative: str) -> Path:
        """Absolute path inside the build folder for a new output; its parent folder is created."""
        path = self.folder / relative
        path.parent.mkdir(parents=True, exist_ok=True)
        return path

    def log_path(self, stage: str) -> Path:
        return self.output_path(f"logs/{stage}.log")

    def note(self, message: str) -> None:
        """A line for the person watching the build (progress output, not the manifest)."""
        self.notify(message)
