"""A mapkit build folder opened for driving: manifest, OpenDRIVE file, map hash, collision world."""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

from tavf_mapkit.errors import InputError
from tavf_mapkit.pipeline.manifest import file_sha256

# A map without <geoReference> (many hand-made and tool-made OpenDRIVE files) is placed as CARLA places it:
# local (0, 0) at 0 deg N, 0 deg E on a transverse Mercator, so GNSS fixes and lat/lon exist (docs/twin.md).
NO_GEOREFERENCE_FALLBACK = "+proj=tmerc +lat_0=0 +lon_0=0 +k=1 +x_0=0 +y_0=0 +ellps=WGS84 +units=m +no_defs"


def georeference_for_driving(odr):
    """(the map's georeference, False), or (the fallback at 0 deg N 0 deg E, True) for a map without one."""
    if odr.georeference is not None:
        return odr.georeference, False
    from tavf_mapkit.opendrive.georef import GeoReference

    return GeoReference(NO_GEOREFERENCE_FALLBACK), True


@dataclass(frozen=True, eq=False)
class Build:
    path: Path
    manifest: dict
    xodr: Path

    @staticmethod
    def open(path: str | Path) -> Build:
        folder = Path(path)
        if not folder.is_dir():
            raise InputError("not a build folder (no such directory)", file=str(folder))
        manifest_path = folder / "manifest.json"
        if not manifest_path.is_file():
            raise InputError("not a build folder (no manifest.json; make one with `mapkit build`)", file=str(folder))
        try:
            manifest = json.loads(manifest_path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as error:
            raise InputError(f"manifest.json is unreadable: {error}", file=str(manifest_path)) from None
        if not isinstance(manifest, dict):
            raise InputError("manifest.json is not a JSON object", file=str(manifest_path))
        artifact = (manifest.get("artifacts") or {}).get("xodr") or {}
        name = manifest.get("name") or folder.name
        xodr = folder / artifact["path"] if artifact.get("path") else folder / f"{name}.xodr"
        if not xodr.is_file():
            raise InputError("the build has no OpenDRIVE file (did the build fail?)", file=str(xodr))
        return Build(folder, manifest, xodr)

    @property
    def name(self) -> str:
        return str(self.manifest.get("name") or self.path.name)

    @cached_property
    def map_sha256(self) -> str:
        """sha256 of the OpenDRIVE file, from the manifest when it lists it, else computed."""
        artifact = (self.manifest.get("artifacts") or {}).get("xodr") or {}
        return artifact.get("sha256") or file_sha256(self.xodr)

    @property
    def collision_world(self) -> Path:
        return self.path / "collision" / "world.json"

    @property
    def net_xml(self) -> Path | None:
        artifact = (self.manifest.get("artifacts") or {}).get("net") or {}
        path = self.path / artifact["path"] if artifact.get("path") else self.path / f"{self.name}.net.xml"
        return path if path.is_file() else None
