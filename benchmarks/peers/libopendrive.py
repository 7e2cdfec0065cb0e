"""The exact oracle: libOpenDRIVE's lane borders (C++, ../shared/tools/libopendrive, compiled here once).

    >>> rows = lane_borders("map.xodr", step=0.5)      # structured rows: road, section_s0, lane, s, x, y, z
    >>> agreement = border_agreement(load_opendrive("map.xodr"), rows, 0.5)

The program prints the outer border of every lane of every lane section at s0 + k*step (s <= section end), at
h = 0 without lane height: the format of ../shared/data/reference/lane_borders.
"""

from __future__ import annotations

import hashlib
import io
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from .cache import INSTALL_HINT, PEERS_DIR, SHARED_TOOLS, PeerUnavailable

TOOL = SHARED_TOOLS / "libopendrive"
APT = "apt-get install -y g++ libpugixml-dev"


def _source_digest() -> str:
    digest = hashlib.sha256()
    for name in ("build.sh", "dump_borders.cpp", *sorted(p.name for p in TOOL.glob("libOpenDRIVE-*.tar.gz"))):
        digest.update((TOOL / name).read_bytes())
    return digest.hexdigest()[:16]


def binary(install: bool = False) -> Path:
    """The compiled dump_borders, built from ../shared/tools/libopendrive if ``install`` (about a minute)."""
    if not (TOOL / "build.sh").is_file():
        raise PeerUnavailable(
            f"peer libopendrive: {TOOL}/build.sh not found (../shared/tools beside the checkout)"
        )
    folder = PEERS_DIR / "libopendrive"
    program, marker = folder / "dump_borders", folder / ".installed"
    source = _source_digest()
    if program.is_file() and marker.is_file() and marker.read_text().strip() == source:
        return program
    if not install:
        raise PeerUnavailable(
            f"peer libopendrive is not built in {folder}: run {INSTALL_HINT} libopendrive (needs {APT})"
        )
    missing = [
        what
        for what, there in (
            ("g++", shutil.which("g++")),
            ("pugixml headers", Path("/usr/include/pugixml.hpp").is_file()),
        )
        if not there
    ]
    if missing:
        raise PeerUnavailable(f"peer libopendrive cannot be built: no {' and no '.join(missing)} ({APT})")
    folder.mkdir(parents=True, exist_ok=True)
    print(f"building {program} from {TOOL} (about a minute) ...", file=sys.stderr)
    with tempfile.TemporaryDirectory(dir=folder) as tmp:
        built = Path(tmp) / "dump_borders"
        done = subprocess.run(
            ["bash", str(TOOL / "build.sh"), str(built)],
            capture_output=True,
            text=True,
            timeout=1800,
            check=False,
        )
        if done.returncode != 0 or not built.is_file():
            reason = (done.stderr.strip().splitlines() or ["no output"])[-1][:300]
            raise PeerUnavailable(f"peer libopendrive: build.sh failed: {reason}")
        built.replace(program)  # atomic: a half-built binary is never the cached one
    marker.write_text(source + "\n")
    return program


def lane_borders(xodr: Path | str, step: float = 0.5, program: Path | None = None):
    """Every lane border of ``xodr`` as libOpenDRIVE evaluates it (rows as ``borders.read_borders``)."""
    from .borders import read_borders  # numpy, which installing the peer (install.py) does not need

    program = program or binary()
    done = subprocess.run(
        [str(program), str(xodr), repr(float(step))], capture_output=True, text=True, timeout=900, check=False
    )
    if done.returncode != 0:
        raise RuntimeError(
            f"libopendrive failed on {xodr} (exit {done.returncode}): "
            f"{(done.stderr.strip().splitlines() or ['no output'])[-1][:300]}"
        )
    return read_borders(io.StringIO(done.stdout))
