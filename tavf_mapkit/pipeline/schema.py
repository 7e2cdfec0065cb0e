"""What a pipeline file may say: its tables, their keys, and each key's type and range, checked on load.

Checked before anything is built, so a typo (``[mesh] epsilon = 0.1``) or a wrong type (``[check.thresholds]
gnss_p95_distance_m = "15"``) is a one-line error naming the file, table and key, instead of a value that is
silently ignored or a traceback deep inside a stage. A stage that reads a new key declares it in ``TABLES``.
The table of a stage that is not described here (a plug-in stage, or one listed in [pipeline] stages that is
not installed) is kept unchecked: that stage owns it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from tavf_mapkit.errors import InputError


@dataclass(frozen=True)
class Setting:
    """One key: ``accepts(value)`` says whether a value is allowed, ``expected`` says what is, for people."""

    expected: str
    accepts: Callable[[object], bool]


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def metres() -> Setting:
    return Setting("a positive number of metres", lambda value: _is_number(value) and value > 0)


def non_negative(unit: str) -> Setting:
    return Setting(f"a number >= 0 ({unit})", lambda value: _is_number(value) and value >= 0)


def fraction() -> Setting:
    return Setting("a number from 0 to 1", lambda value: _is_number(value) and 0 <= value <= 1)


def count() -> Setting:
    return Setting("a whole number >= 0", lambda value: isinstance(value, int) and not isinstance(value, bool)
                   and value >= 0)


def boolean() -> Setting:
    return Setting("true or false", lambda value: isinstance(value, bool))


def text() -> Setting:
    return Setting("a non-empty string", lambda value: isinstance(value, str) and value.strip() != "")


def choice(*options: str) -> Setting:
    return Setting(f"one of {', '.join(options)}", lambda value: isinstance(value, str) and value in options)


def file_path() -> Setting:
    # strings of keys ending in _path are resolved relative to the pipeline file before this check
    return Setting("a file path (a string, relative to the pipeline file)",
                   lambda value: isinstance(value, Path))


def profile() -> Setting:
    return Setting("a profile name (carla, full) or a .toml path",
                   lambda value: isinstance(value, Path) or isinstance(value, str) and value.strip() != "")


def stage_list() -> Setting:
    return Setting("a list of stage names", lambda value: isinstance(value, list) and value != [] and
                   all(isinstance(item, str) and item.strip() != "" for item in value))


def bbox() -> Setting:
    return Setting("[west, south, east, north] in degrees",
                   lambda value: isinstance(value, list) and len(value) == 4 and all(map(_is_number, value)))


def _thresholds() -> dict[str, Setting]:
    from tavf_mapkit.pipeline.builtin.check import THRESHOLDS

    settings = {key: non_negative("metres") for key in THRESHOLDS}
    settings["reference_min_coverage"] = fraction()  # a share of the reference network's length
    return settings


def _validation() -> dict:
    """[check.validation]: how many validation findings the build's OpenDRIVE may have;
    [check.validation.rules] takes validator rule ids as keys (a typo is an unknown key, not a limit that never applies)."""
    from tavf_mapkit.validate import all_rules

    return {"max_errors": count(), "max_warnings": count(), "rules": {rule: count() for rule in all_rules()}}


def _tables() -> dict[str, dict]:
    """Table name -> {key: Setting, or a dict for a nested table}; built on use (imports the check stage)."""
    from tavf_mapkit.netconvert import CRS_CHOICES

    return {
        "pipeline": {"name": text(), "stages": stage_list(), "driving_side": choice("auto", "left", "right")},
        "area": {"bbox": bbox(), "polygon_path": file_path()},
        "extract": {"routes": boolean()},
        "netconvert": {"profile": profile(), "crs": choice(*CRS_CHOICES)},
        "opendrive": {"repair": boolean(), "curves": choice("arcs", "keep")},
        "mesh": {"eps": metres(), "tile": metres(), "format": choice("glb", "obj"), "solids": boolean()},
        "collision": {"eps": metres(), "tile": metres()},
        "check": {"reference_network_path": file_path(), "gnss_trace_path": file_path(),
                  "thresholds": _thresholds(), "validation": _validation()},
        "report": {},
    }


def check_tables(sections: dict, *, file: str | None, stage_names: tuple[str, ...] = ()) -> None:
    """Raise a one-line InputError for the first unknown table or key, or value of the wrong type or range.

    ``sections`` are the pipeline's tables (paths already resolved); ``stage_names`` those it lists, whose
    tables are allowed even when this module does not describe them.
    """
    tables = _tables()
    for name, values in sections.items():
        if not isinstance(values, dict):
            raise InputError(f"top-level key {name!r} must be a table ([{name}])", file=file)
        if name in tables:
            _check_table(name, values, tables[name], file)
        elif name not in stage_names and not _is_registered_stage(name):
            known = sorted(set(tables) | set(stage_names))
            raise InputError(f"[{name}] is not a table of a pipeline file (known: {', '.join(known)})",
                             file=file)


def check_value(table: str, key: str, value, setting: Setting, file: str | None = None) -> None:
    if not setting.accepts(value):
        raise InputError(f"[{table}] {key} must be {setting.expected}, not {_shown(value)}", file=file)


def _check_table(name: str, values: dict, settings: dict, file: str | None) -> None:
    for key, value in values.items():
        setting = settings.get(key)
        if setting is None:
            known = ", ".join(sorted(settings)) or "none"
            raise InputError(f"[{name}] unknown key {key!r} (known: {known})", file=file)
        if isinstance(setting, dict):
            if not isinstance(value, dict):
                raise InputError(f"[{name}] {key} must be a table ([{name}.{key}])", file=file)
            _check_table(f"{name}.{key}", value, setting, file)
        else:
            check_value(name, key, value, setting, file)


def _is_registered_stage(name: str) -> bool:
    from tavf_mapkit.pipeline.stages import get_stage

    return get_stage(name) is not None


def _shown(value) -> str:
    """The offending value as TOML would spell it (short): a wrong type is what the reader has to find."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, Path):
        return repr(str(value))
    shown = repr(value)
    return shown if len(shown) <= 40 else shown[:37] + "..."
