"""The two files of a build folder that traffic needs: the SUMO network and the OpenDRIVE map."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from tavf_mapkit.errors import InputError

MANIFEST = "manifest.json"


@dataclass(frozen=True)
class BuildFiles:
    folder: Path
    name: str
    net: Path
    xodr: Path


def build_files(build_dir: str | Path) -> BuildFiles:
    """``NAME.net.xml`` and ``NAME.xodr`` of a build, as the manifest's artifacts name them."""
    folder = Path(build_dir)
    manifest_path = folder / MANIFEST
    if not manifest_path.is_file():
        raise InputError("not a build folder (no manifest.json); make one with `mapkit build INPUT -o FOLDER`",
                         file=str(folder))
    try:
        manifest = json.loads(manifest_path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as error:
        raise InputError(f"unreadable manifest: {error}", file=str(manifest_path)) from None
    artifacts = manifest.get("artifacts") if isinstance(manifest, dict) else None
    name = str(manifest.get("name") or folder.name) if isinstance(manifest, dict) else folder.name
    paths = {}
    for key, suffix in (("net", ".net.xml"), ("xodr", ".xodr")):
        relative = (artifacts or {}).get(key, {}).get("path") if isinstance(artifacts, dict) else None
        path = folder / (relative or f"{name}{suffix}")
        if not path.is_file():
            if key == "net" and _input_kind(manifest) == "opendrive":
                raise InputError("the build was made from an OpenDRIVE file and has no SUMO network, which SUMO "
                                 "traffic (--traffic, --pedestrians, --demand) needs: build from OSM or a SUMO "
                                 "network for traffic", file=str(folder))
            raise InputError(f"the build has no {name}{suffix} (artifact {key!r}); rebuild it with mapkit build",
                             file=str(folder))
        paths[key] = path
    return BuildFiles(folder, name, paths["net"], paths["xodr"])


def _input_kind(manifest) -> str | None:
    record = manifest.get("input") if isinstance(manifest, dict) else None
    return record.get("kind") if isinstance(record, dict) else None
