"""The netconvert stage: OSM or a SUMO network -> NAME.net.xml + NAME.xodr in one run of SUMO's netconvert.

netconvert is the binary of the ``eclipse-sumo`` wheel, run as a subprocess. Its options come from a named
profile (package data ``tavf_mapkit/data/profiles/NAME.toml``, see docs/netconvert-profiles.md); all of its
output goes to a log, warnings are counted by kind, and its first error becomes a one-line StageError.

Projection (docs/netconvert-profiles.md, "Projection"):
- OSM input: ``--proj`` with a transverse Mercator centred on the extract (default), or ``--proj.utm``.
  The extract's nodes can reach far beyond the roads netconvert imports (rivers, boundaries, a long cycleway:
  Krems' roads lay up to 9.6 km from the extract's centre, where single-precision readers such as CARLA are
  0.2-0.4 mm off); when the network's own centre lies far from the origin, netconvert runs once more with the
  projection centred on the network (``centre_on_network``).
- SUMO network input: netconvert ``-s`` ignores ``--proj`` for the coordinates and only rewrites the
  label (checked with netconvert 1.28: convBoundary and netOffset unchanged, projParameter replaced), so a
  re-projection goes through netconvert's plain-XML export in geographic coordinates and back
  (``--crs tmerc``/``utm``). ``--crs keep`` keeps the network's own coordinates exactly.
"""

from __future__ import annotations

import functools
import math
import os
import re
import shutil
import subprocess
import sys
import time
import tomllib
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from tavf_mapkit.data import data_path
from tavf_mapkit.errors import InputError, StageError
from tavf_mapkit.projection import as_tmerc, tmerc_centred_on

PROFILES_DIR = data_path("profiles")
CRS_CHOICES = ("tmerc", "utm", "keep")
# Options every run gets: no schema look-ups (hermetic, no network), every warning on its own line so the
# log can be counted by kind (netconvert otherwise folds repeats into "N total messages of type ...").
_ALWAYS = ["--xml-validation=never", "--xml-validation.net=never", "--aggregate-warnings=-1"]
# With our centred transverse Mercator the projected coordinates are already small, so netconvert's shift of
# the network to (0, 0) is switched off: local (0, 0) is then +lat_0/+lon_0 and the OpenDRIVE needs no
# <offset>, which CARLA ignores (it would misplace the map by the offset). SUMO's netOffset becomes 0.
_AT_PROJECTION_ORIGIN = ["--offset.disable-normalization=true"]
# netconvert runs again with the projection centred on the network when the network's centre lies more than
# OFF_CENTRE_M from the origin and more than OFF_CENTRE_SHARE of the network's half-diagonal: single-precision
# readers lose about 0.05 mm per km from the origin (CARLA's waypoints on Krems: median 0.17 mm with the
# roads 2-10 km from it, 0.07 mm centred), so a nearer centre is not worth a second run.
OFF_CENTRE_M = 1000.0
OFF_CENTRE_SHARE = 0.25
_QUOTED = re.compile(r"'[^']*'")
_NUMBER = re.compile(r"(?<![A-Za-z_])-?\d+(?:\.\d+)?")
_NUMBER_RUN = re.compile(r"#(?:[#,]*#)?")


@functools.lru_cache(maxsize=1)
def find_netconvert() -> Path:
    """The netconvert binary: $TAVF_NETCONVERT, the eclipse-sumo wheel's, next to python, or on PATH."""
    candidates = []
    if os.environ.get("TAVF_NETCONVERT"):
        candidates.append(Path(os.environ["TAVF_NETCONVERT"]))
    try:
        import sumo

        candidates.append(Path(sumo.SUMO_HOME) / "bin" / "netconvert")
    except ImportError:
        pass
    candidates.append(Path(sys.executable).parent / "netconvert")
    on_path = shutil.which("netconvert")
    if on_path:
        candidates.append(Path(on_path))
    for candidate in candidates:
        if candidate.is_file() and os.access(candidate, os.X_OK):
            return candidate
    raise StageError("netconvert not found: install the eclipse-sumo wheel (pip install eclipse-sumo)")


@functools.lru_cache(maxsize=4)
def netconvert_version(binary: Path | None = None) -> str:
    """First line of ``netconvert --version``, e.g. "Eclipse SUMO netconvert 1.28.0"."""
    binary = binary or find_netconvert()
    try:
        completed = subprocess.run([str(binary), "--version"], capture_output=True, text=True, timeout=60,
                                   check=False)
    except (OSError, subprocess.TimeoutExpired) as error:
        raise StageError(f"cannot run {binary} --version: {error}") from None
    lines = (completed.stdout or completed.stderr).strip().splitlines()
    return lines[0].strip() if lines else "unknown"


# --------------------------------------------------------------------------------------------- profiles


@dataclass(frozen=True)
class Profile:
    """A named set of netconvert options: ``options`` for every input, ``osm`` only for OSM input."""

    name: str
    description: str
    options: dict = field(default_factory=dict)
    osm: dict = field(default_factory=dict)
    source: str = ""

    def options_for(self, kind: str) -> dict:
        """The options for an input kind ("osm" or "sumo-net"), OSM-only ones last."""
        return {**self.options, **self.osm} if kind == "osm" else dict(self.options)

    def to_dict(self) -> dict:
        return {"name": self.name, "options": self.options, "osm": self.osm}


def load_profile(name_or_path: str | Path) -> Profile:
    """A profile by name (``carla``, ``full``: data/profiles/NAME.toml) or by path to a .toml file.

    A profile may say ``extends = "carla"``; its tables are then laid over the parent's.
    """
    path = _profile_path(name_or_path)
    name = str(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as error:
        raise InputError(f"cannot read netconvert profile: {error.strerror}", file=name) from None
    except tomllib.TOMLDecodeError as error:
        raise InputError(f"not valid TOML: {error}", file=name) from None
    unknown = set(data) - {"description", "extends", "options", "osm"}
    if unknown:
        raise InputError(f"unknown keys in netconvert profile: {', '.join(sorted(unknown))}", file=name)
    options, osm = {}, {}
    if data.get("extends"):
        parent = load_profile(_relative_profile(data["extends"], path))
        options, osm = dict(parent.options), dict(parent.osm)
    for table, target in (("options", options), ("osm", osm)):
        values = data.get(table, {})
        if not isinstance(values, dict):
            raise InputError(f"[{table}] must be a table of netconvert options", file=name)
        for key, value in values.items():
            _check_option_value(key, value, name)
            target[key] = value
    return Profile(path.stem, str(data.get("description", "")), options, osm, str(path))


def option_arguments(options: dict) -> list[str]:
    """``{"geometry.remove": True, "keep-edges.by-type": [...]} -> ["--geometry.remove=true", ...]``."""
    arguments = []
    for key, value in options.items():
        if isinstance(value, bool):
            text = "true" if value else "false"
        elif isinstance(value, (list, tuple)):
            text = ",".join(str(item) for item in value)
        else:
            text = str(value)
        arguments.append(f"--{key}={text}")
    return arguments


def _profile_path(name_or_path: str | Path) -> Path:
    text = str(name_or_path)
    if text.endswith(".toml") or os.sep in text:
        path = Path(text)
    else:
        path = PROFILES_DIR / f"{text}.toml"
        if not path.is_file():
            known = sorted(p.stem for p in PROFILES_DIR.glob("*.toml"))
            raise InputError(f"unknown netconvert profile {text!r} (known: {', '.join(known) or 'none'})")
    if not path.is_file():
        raise InputError("netconvert profile not found", file=str(path))
    return path


def _relative_profile(parent: str, child: Path) -> str | Path:
    if parent.endswith(".toml"):
        return child.parent / parent
    sibling = child.parent / f"{parent}.toml"
    return sibling if sibling.is_file() else parent


def _check_option_value(key: str, value, source: str) -> None:
    if not re.fullmatch(r"[A-Za-z][A-Za-z0-9._-]*", key):
        raise InputError(f"{key!r} is not a netconvert option name", file=source)
    scalar = (bool, int, float, str)
    if isinstance(value, list):
        if not all(isinstance(item, scalar) for item in value):
            raise InputError(f"option {key}: list items must be plain values", file=source)
    elif not isinstance(value, scalar):
        raise InputError(f"option {key}: expected a boolean, number, string or list", file=source)


# --------------------------------------------------------------------------------------------- messages


@dataclass
class Messages:
    """netconvert's warnings counted by kind (ids and numbers replaced by placeholders) and its errors."""

    warnings: Counter = field(default_factory=Counter)
    errors: list[str] = field(default_factory=list)

    def add_output(self, text: str) -> None:
        lines = text.splitlines()
        for index, line in enumerate(lines):
            if line.startswith("Warning: "):
                self.warnings[warning_kind(line[len("Warning: "):])] += 1
            elif line.startswith("Error: "):
                # an error may continue on indented lines ("Error: On processing option ...:\n No option ...")
                message = line[len("Error: "):].strip()
                for follow in lines[index + 1:]:
                    if not follow.startswith(" "):
                        break
                    message = f"{message} {follow.strip()}"
                self.errors.append(message)

    def to_dict(self, top: int = 20) -> dict:
        return {
            "warnings": sum(self.warnings.values()),
            "warnings_by_kind": dict(self.warnings.most_common(top)),
            "warning_kinds": len(self.warnings),
            "errors": len(self.errors),
        }


def warning_kind(message: str) -> str:
    """A warning with its ids and numbers replaced, so repeats of one problem count as one kind."""
    numbered = _NUMBER.sub("#", _QUOTED.sub("'%'", message.strip()))
    return _NUMBER_RUN.sub("#", numbered)  # "23182274#3" or "-794,-795" -> "#"


# --------------------------------------------------------------------------------------------- running


@dataclass
class Conversion:
    """What one conversion did: the files, the projection passed, and netconvert's messages."""

    net: Path
    xodr: Path
    log: Path
    version: str
    projection: str
    commands: list[list[str]] = field(default_factory=list)
    messages: Messages = field(default_factory=Messages)
    notes: list[str] = field(default_factory=list)
    seconds: float = 0.0
    cwd: Path = field(default_factory=Path.cwd)

    def to_dict(self) -> dict:
        return {
            "netconvert": self.version,
            "projection": self.projection,
            "commands": [" ".join(_quote(part) for part in ["netconvert", *command[1:]])
                         for command in self.commands],
            "notes": self.notes,
            "seconds": round(self.seconds, 3),
            **self.messages.to_dict(),
        }


def convert(source: Path, kind: str, net: Path, xodr: Path, log: Path, profile: Profile, *,
            crs: str = "tmerc", centre: tuple[float, float] | None = None,
            clip_bbox: tuple[float, float, float, float] | None = None,
            cwd: Path | None = None, lefthand: bool | None = None) -> Conversion:
    """Run netconvert on ``source`` (kind "osm" or "sumo-net") and write ``net`` and ``xodr``.

    ``centre`` (lon, lat) is where the transverse Mercator of an OSM input is centred (the extract's bbox
    centre); a SUMO network is centred on its own nodes. ``clip_bbox`` (W,S,E,N) keeps only the edges of a
    SUMO network inside it (an OSM input is clipped by the extract stage instead). Relative paths are
    relative to ``cwd``, where netconvert runs, so the commands in the log name files of the build folder.
    ``lefthand`` passes ``--lefthand`` (left-hand traffic) explicitly; None leaves netconvert's default (right-hand
    for OSM, a SUMO network's own ``lefthand`` attribute, which a re-projection through plain XML would lose).
    """
    if crs not in CRS_CHOICES:
        raise InputError(f"unknown --crs {crs!r} (choose {', '.join(CRS_CHOICES)})")
    binary = find_netconvert()
    started = time.perf_counter()
    base = Path(cwd) if cwd is not None else Path.cwd()
    conversion = Conversion(net, xodr, log, netconvert_version(binary), projection="", cwd=base)
    (base / log).parent.mkdir(parents=True, exist_ok=True)
    with (base / log).open("w", encoding="utf-8") as log_file:
        log_file.write(f"# {conversion.version}\n")
        outputs = ["--output-file", str(net), "--opendrive-output", str(xodr)]
        profile_arguments = option_arguments(profile.options_for(kind))
        if lefthand is not None:
            profile_arguments.append(f"--lefthand={'true' if lefthand else 'false'}")
        if kind == "osm":
            projection = _osm_projection(crs, centre)
            conversion.projection = projection[1] if len(projection) > 1 else "UTM zone of the data"
            command = [str(binary), "--osm-files", str(source), *projection, *profile_arguments, *_ALWAYS,
                       *outputs]
            _run(command, log_file, conversion, source)
            if crs == "tmerc":
                centre_on_network(command, log_file, conversion, source)
        elif kind == "sumo-net":
            _convert_sumo_net(binary, source, crs, profile_arguments, clip_bbox, outputs, log_file,
                              conversion)
        else:
            raise InputError(f"unknown input kind {kind!r}", file=str(source))
    for path in (net, xodr):
        if not (base / path).is_file() or (base / path).stat().st_size == 0:
            raise StageError(f"netconvert reported success but wrote no {path.name} (see {log})",
                             file=str(source))
    conversion.seconds = time.perf_counter() - started
    return conversion


def _osm_projection(crs: str, centre: tuple[float, float] | None) -> list[str]:
    if crs == "utm":
        return ["--proj.utm"]
    if crs == "keep":
        raise InputError("--crs keep needs a SUMO network input (an OSM file has no projection to keep)")
    if centre is None:
        raise StageError("no centre for the transverse Mercator projection (the extract has no nodes)")
    return ["--proj", tmerc_centred_on(*centre), *_AT_PROJECTION_ORIGIN]


def _convert_sumo_net(binary: Path, source: Path, crs: str, profile_arguments: list[str], clip_bbox,
                      outputs: list[str], log_file, conversion: Conversion) -> None:
    from tavf_mapkit.sumonet import read_location

    location = read_location(conversion.cwd / source)
    clip = []
    if clip_bbox:
        clip = [f"--keep-edges.in-geo-boundary={','.join(repr(float(v)) for v in clip_bbox)}"]
    if crs == "keep" or not location.georeferenced:
        if crs != "keep":
            conversion.notes.append("the network has no georeference: kept its coordinates")
        # netconvert -s relabels instead of re-projecting, so the label must describe the same projection;
        # as_tmerc writes UTM as the identical transverse Mercator so that +lat_0/+lon_0 are explicit.
        relabel = as_tmerc(location.proj) if location.georeferenced else None
        projection = ["--proj", relabel] if relabel and relabel != location.proj else []
        conversion.projection = relabel or location.proj
        command = [str(binary), "--sumo-net-file", str(source), *projection, *clip, *profile_arguments,
                   *_ALWAYS, *outputs]
        _run(command, log_file, conversion, source)
        if projection:
            written = read_location(conversion.cwd / conversion.net)
            if written.net_offset != location.net_offset:
                raise StageError("netconvert re-projected the network while relabelling its projection "
                                 f"(netOffset {location.net_offset} -> {written.net_offset})",
                                 file=str(source))
            conversion.notes.append(f"kept the network's coordinates; geoReference {location.proj!r} "
                                    f"written as the identical {relabel!r}")
        return

    # Re-project: export plain XML in lon/lat (9 decimals, ~0.1 mm), rebuild it with the new projection.
    # The type file is left out on purpose: its defaults (e.g. sidewalkWidth) would add lanes on re-import.
    # a fixed name (not a random temp name) keeps the recorded commands identical from build to build
    folder = conversion.cwd / conversion.log.parent / "netconvert-plain"
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    try:
        prefix = Path(os.path.relpath(folder, conversion.cwd)) / "plain"
        export = [str(binary), "--sumo-net-file", str(source), "--plain-output-prefix", str(prefix),
                  "--proj.plain-geo=true", "--precision.geo=9", *_ALWAYS]
        _run(export, log_file, conversion, source)
        if crs == "utm":
            projection = ["--proj.utm"]
            conversion.projection = "UTM zone of the data"
        else:
            from tavf_mapkit.sumonet import plain_geo_centre

            nodes = conversion.cwd / f"{prefix}.nod.xml"
            projection = ["--proj", tmerc_centred_on(*plain_geo_centre(nodes)), *_AT_PROJECTION_ORIGIN]
            conversion.projection = projection[1]
        plain_inputs = ["--node-files", f"{prefix}.nod.xml", "--edge-files", f"{prefix}.edg.xml"]
        for option, suffix in (("--connection-files", "con"), ("--tllogic-files", "tll")):
            if (conversion.cwd / f"{prefix}.{suffix}.xml").is_file():
                plain_inputs += [option, f"{prefix}.{suffix}.xml"]
        command = [str(binary), *plain_inputs, *projection, *clip, *profile_arguments, *_ALWAYS, *outputs]
        _run(command, log_file, conversion, source)
        if crs == "tmerc":  # the nodes' centre is the network's, unless --bbox clipped it
            centre_on_network(command, log_file, conversion, source)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    conversion.notes.append(f"re-projected the network from {location.proj!r} via plain XML in lon/lat")


def centre_on_network(command: list[str], log_file, conversion: Conversion, source: Path) -> None:
    """Run ``command`` (which passed ``--proj`` with a transverse Mercator at local (0, 0), no <offset>) once
    more with the projection centred on the network it wrote, when the network's centre lies more than
    OFF_CENTRE_M and more than OFF_CENTRE_SHARE of its half-diagonal from the origin.

    A new projection centre, not a shift of the coordinates (+x_0/+y_0 or <offset>): CARLA 0.9.16 places local
    (0, 0) at +lat_0/+lon_0 and ignores both, so its geolocation would be off by the shift. Centred anew, the
    SUMO network and the OpenDRIVE file stay in one plane, for a map of any size. netconvert lays the same
    network out again: the OSM nodes land where they were, and lane borders move by netconvert's own rounding
    in the plane (Krems: a median 5 mm, as much as from moving the centre by 7 mm), not by the projections'
    difference in scale (1e-6)."""
    from tavf_mapkit.sumonet import read_location

    location = read_location(conversion.cwd / conversion.net)
    west, south, east, north = location.conv_boundary
    if location.net_offset != (0.0, 0.0) or not (west <= east and south <= north):
        return  # not at the projection's origin (or an empty network): nothing this can centre
    off = math.hypot(0.5 * (west + east), 0.5 * (south + north))
    if off <= max(OFF_CENTRE_M, OFF_CENTRE_SHARE * 0.5 * math.hypot(east - west, north - south)):
        return
    centre = location.centre_wgs84()
    if centre is None:
        return
    at = command.index("--proj") + 1
    centred = tmerc_centred_on(*centre)
    conversion.messages = Messages()  # the first run's output is replaced, and its messages with it
    _run([*command[:at], centred, *command[at + 1:]], log_file, conversion, source)
    conversion.projection = centred
    conversion.notes.append(f"centred the projection on the road network (lon {centre[0]}, lat {centre[1]}): "
                            f"its centre lay {off:.0f} m from the origin of {command[at]!r}")


def _run(command: list[str], log_file, conversion: Conversion, source: Path) -> None:
    """Run one netconvert command, append its output to the log, raise StageError on failure."""
    conversion.commands.append(command)
    log_file.write("$ " + " ".join(_quote(part) for part in command) + "\n")
    log_file.flush()
    try:
        completed = subprocess.run(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                   errors="replace", cwd=conversion.cwd, check=False)
    except OSError as error:
        raise StageError(f"cannot run netconvert: {error}") from None
    log_file.write(completed.stdout)
    log_file.write(f"# exit code {completed.returncode}\n")
    log_file.flush()
    messages = Messages()
    messages.add_output(completed.stdout)
    conversion.messages.warnings.update(messages.warnings)
    conversion.messages.errors.extend(messages.errors)
    if completed.returncode != 0 or messages.errors:
        if messages.errors:
            detail = messages.errors[0]
            if detail == "No edges loaded.":
                detail += " (no road of the profile's types in the input?)"
        elif completed.returncode < 0:
            detail = f"crashed with signal {-completed.returncode}"
        else:
            detail = f"exited with code {completed.returncode} without an error message"
        raise StageError(f"netconvert: {detail}", file=str(source))


def _quote(part: str) -> str:
    return f"'{part}'" if (" " in part or not part) else part
