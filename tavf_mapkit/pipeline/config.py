"""Pipeline files (pipelines/NAME.toml) and the command-line options that override them.

A pipeline file is TOML with one table per concern ([pipeline], [area], [extract], [netconvert], and one
per later stage: [mesh], [collision], [check], ...). String values of keys ending in ``_path`` are file
paths relative to the pipeline file; they are resolved when the file is loaded, so a pipeline works from
any current directory. pipelines/tavf.toml is the commented example.
"""

from __future__ import annotations

import copy
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from tavf_mapkit.errors import InputError
from tavf_mapkit.pipeline.stages import DEFAULT_STAGES

DEFAULT_PROFILE = "carla"
DEFAULT_CRS = "tmerc"


@dataclass(frozen=True)
class PipelineConfig:
    """A resolved pipeline: its file (None for the defaults), stage names and per-section options."""

    file: Path | None = None
    name: str | None = None
    stages: tuple[str, ...] = DEFAULT_STAGES
    sections: dict = field(default_factory=dict)

    def section(self, name: str) -> dict:
        """The options of one table (a copy; empty if the pipeline has none)."""
        return copy.deepcopy(self.sections.get(name, {}))

    def path_options(self) -> dict[str, Path]:
        """Every path-valued option as ``{"section.key": Path}`` (they are build inputs)."""
        found = {}
        for section, values in self.sections.items():
            if isinstance(values, dict):
                _collect_paths(values, section, found)
        return found

    def with_overrides(self, *, bbox=None, polygon: Path | None = None, profile: str | None = None,
                       crs: str | None = None) -> PipelineConfig:
        """A copy with command-line options applied (an area option replaces the pipeline's area)."""
        sections = copy.deepcopy(self.sections)
        if bbox is not None or polygon is not None:
            sections["area"] = {"bbox": list(bbox)} if bbox is not None else {"polygon_path": Path(polygon)}
        netconvert = sections.setdefault("netconvert", {})
        if profile is not None:
            netconvert["profile"] = profile
        if crs is not None:
            netconvert["crs"] = crs
        config = PipelineConfig(self.file, self.name, self.stages, sections)
        config.validate()
        return config

    def validate(self) -> None:
        where = str(self.file) if self.file else None
        area = self.sections.get("area", {})
        if "bbox" in area and "polygon_path" in area:
            raise InputError("[area] has both bbox and polygon_path; give one", file=where)
        if "bbox" in area:
            from tavf_mapkit.osm.area import bbox_area

            bbox = area["bbox"]
            if not isinstance(bbox, (list, tuple)) or len(bbox) != 4 or \
                    not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in bbox):
                raise InputError("[area] bbox must be [west, south, east, north] in degrees", file=where)
            bbox_area(bbox)
        netconvert = self.sections.get("netconvert", {})
        if not isinstance(netconvert.get("profile", DEFAULT_PROFILE), (str, Path)):
            raise InputError("[netconvert] profile must be a name (carla, full) or a .toml path", file=where)
        from tavf_mapkit.netconvert import CRS_CHOICES

        if netconvert.get("crs", DEFAULT_CRS) not in CRS_CHOICES:
            raise InputError(f"[netconvert] crs must be one of {', '.join(CRS_CHOICES)}", file=where)
        routes = self.sections.get("extract", {}).get("routes", False)
        if not isinstance(routes, bool):
            raise InputError("[extract] routes must be true or false", file=where)

    def to_dict(self) -> dict:
        return {"file": str(self.file) if self.file else None, "name": self.name, "stages": list(self.stages),
                "sections": _jsonable(self.sections)}


def load_pipeline(path: str | Path | None) -> PipelineConfig:
    """Read a pipeline file; None gives the defaults (all stages, profile carla, tmerc, whole input)."""
    if path is None:
        return PipelineConfig()
    path = Path(path)
    name = str(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError("pipeline file not found", file=name) from None
    except (OSError, UnicodeDecodeError) as error:
        raise InputError(f"cannot read pipeline file: {error}", file=name) from None
    except tomllib.TOMLDecodeError as error:
        raise InputError(f"not valid TOML: {error}", file=name) from None
    head = data.pop("pipeline", {})
    if not isinstance(head, dict):
        raise InputError("[pipeline] must be a table", file=name)
    stages = head.get("stages", list(DEFAULT_STAGES))
    if not isinstance(stages, list) or not all(isinstance(stage, str) for stage in stages) or not stages:
        raise InputError("[pipeline] stages must be a list of stage names", file=name)
    for key, value in data.items():
        if not isinstance(value, dict):
            raise InputError(f"top-level key {key!r} must be a table ([{key}])", file=name)
    sections = _resolve_paths(data, path.resolve().parent)
    config = PipelineConfig(path.resolve(), head.get("name") or path.stem, tuple(stages), sections)
    config.validate()
    return config


def _resolve_paths(values, base: Path):
    if isinstance(values, dict):
        resolved = {}
        for key, value in values.items():
            if key.endswith("_path") and isinstance(value, str):
                resolved[key] = (base / value).resolve()
            else:
                resolved[key] = _resolve_paths(value, base)
        return resolved
    if isinstance(values, list):
        return [_resolve_paths(value, base) for value in values]
    return values


def _collect_paths(values: dict, prefix: str, found: dict) -> None:
    for key, value in values.items():
        if isinstance(value, Path):
            found[f"{prefix}.{key}"] = value
        elif isinstance(value, dict):
            _collect_paths(value, f"{prefix}.{key}", found)


def _jsonable(value):
    if isinstance(value, dict):
        return {key: _jsonable(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(item) for item in value]
    if isinstance(value, Path):
        return str(value)
    return value
