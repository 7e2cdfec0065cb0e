"""Where the peers live, and each peer's own Python environment: one venv per peer, made on request."""

from __future__ import annotations

import os
import subprocess
import sys
import venv
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
PEERS_DIR = Path(os.environ.get("TAVF_PEERS_DIR", REPO / "benchmarks" / ".peers"))
SHARED_TOOLS = Path(os.environ.get("TAVF_SHARED_TOOLS", REPO.parent / "shared" / "tools"))
INSTALL_HINT = "python -m benchmarks.peers.install"


class PeerUnavailable(RuntimeError):
    """A peer that is not installed here (and was not to be installed now), with the reason and the remedy."""


def peer_venv(name: str, requirement: str, entry: str, install: bool) -> Path:
    """The venv ``PEERS_DIR/name`` holding ``requirement``; ``entry`` (e.g. ``bin/python``) proves it
    complete.

    A venv whose install failed half-way has no marker file and is made again on the next request."""
    folder = PEERS_DIR / name
    marker = folder / ".installed"
    if marker.is_file() and marker.read_text().strip() == requirement and (folder / entry).exists():
        return folder / entry
    if not install:
        raise PeerUnavailable(
            f"peer {name} ({requirement}) is not installed in {folder}: run {INSTALL_HINT} {name}"
        )
    print(f"creating {folder} with {requirement} ...", file=sys.stderr)
    venv.create(folder, with_pip=True, clear=True)
    done = subprocess.run(
        [str(folder / "bin" / "python"), "-m", "pip", "install", "-q", requirement],
        capture_output=True,
        text=True,
        check=False,
    )
    if done.returncode != 0 or not (folder / entry).exists():
        reason = (done.stderr.strip().splitlines() or ["no output"])[-1][:300]
        raise PeerUnavailable(f"peer {name}: pip install {requirement} failed: {reason}")
    marker.write_text(requirement + "\n")
    return folder / entry
