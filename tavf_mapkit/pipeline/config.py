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
    driving_side: str = "auto"  # [pipeline] driving_side: left, right, or auto (tavf_mapkit/drivingside.py)

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
                       crs: str | None = None, driving_side: str | None = None,
                       repair: bool | None = None) -> PipelineConfig:
        """A copy with command-line options applied (an area option replaces the pipeline's area)."""
        sections = copy.deepcopy(self.sections)
        if repair is not None:
            sections.setdefault("opendrive", {})["repair"] = repair
        if bbox is not None or polygon is not None:
            sections["area"] = {"bbox": list(bbox)} if bbox is not None else {"polygon_path": Path(polygon)}
        netconvert = sections.setdefault("netconvert", {})
        if profile is not None:
            netconvert["profile"] = profile
        if crs is not None:
            netconvert["crs"] = crs
        config = PipelineConfig(self.file, self.name, self.stages, sections,
                                driving_side if driving_side is not None else self.driving_side)
        config.validate()
        return config

    def validate(self) -> None:
        """Every table, key, type and range against the schema (tavf_mapkit/pipeline/schema.py): one line
        naming the file, table and key for the first problem."""
        from tavf_mapkit.pipeline.schema import check_tables

        where = str(self.file) if self.file else None
        check_tables(self.sections, file=where, stage_names=self.stages)
        check_tables({"pipeline": {"driving_side": self.driving_side}}, file=where)
        area = self.sections.get("area", {})
        if "bbox" in area and "polygon_path" in area:
            raise InputError("[area] has both bbox and polygon_path; give one", file=where)
        if "bbox" in area:
            from tavf_mapkit.osm.area import bbox_area

            try:
                bbox_area(area["bbox"])
            except InputError as error:
                raise InputError(f"[area] {error.message}", file=where) from None

    def to_dict(self) -> dict:
        return {"file": str(self.file) if self.file else None, "name": self.name, "stages": list(self.stages),
                "driving_side": self.driving_side, "sections": _jsonable(self.sections)}


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
    from tavf_mapkit.pipeline.schema import check_tables

    check_tables({"pipeline": head}, file=str(path.resolve()))  # named as validate() names it
    stages = head.get("stages", list(DEFAULT_STAGES))
    sections = _resolve_paths(data, path.resolve().parent)
    config = PipelineConfig(path.resolve(), head.get("name") or path.stem, tuple(stages), sections,
                            head.get("driving_side", "auto"))
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
