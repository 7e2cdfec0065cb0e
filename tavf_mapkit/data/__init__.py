"""Runtime data that ships inside the package, so a normal (non-editable) install works from any folder.

- ``profiles/NAME.toml``   netconvert option profiles (``--profile NAME``, docs/netconvert-profiles.md)
- ``baselines/*.json``     the CI accuracy baselines (docs/accuracy.md); in a development checkout this is the
                           file that ``mapkit baseline refresh`` rewrites and git tracks

Declared as package data in pyproject.toml. Located with importlib.resources rather than a path relative to
the repository, which does not exist beside an installed wheel.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path


def data_path(*parts: str) -> Path:
    """A file or folder of the package data as a real path (the package is installed unpacked: wheels are
    never imported from a zip here, and callers record these paths and their sha256 in build manifests)."""
    root = resources.files(__name__)
    return Path(str(root.joinpath(*parts)))
