"""Install the independent oracles into benchmarks/.peers (or $TAVF_PEERS_DIR) for slow tests and benchmarks.

    $ python -m benchmarks.peers.install                  # all: libopendrive carla qc
    $ python -m benchmarks.peers.install libopendrive

Run from the checkout with any Python >= 3.11 (only the standard library is used here). libopendrive needs g++
and Debian's libpugixml-dev (``apt-get install -y g++ libpugixml-dev``, which .ci/run does first under CI).
Already installed peers are kept. Exit code 1 when a peer could not be installed, with one line naming it.
"""

from __future__ import annotations

import argparse
import sys

from . import asam_qc, carla_map, libopendrive
from .cache import PeerUnavailable

PEERS = {
    "libopendrive": lambda: libopendrive.binary(install=True),
    "carla": lambda: carla_map.python(install=True),
    "qc": lambda: asam_qc.program(install=True),
}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("peers", nargs="*", metavar="PEER", help=f"{', '.join(PEERS)} (default: all)")
    names = parser.parse_args(argv).peers or list(PEERS)
    unknown = [name for name in names if name not in PEERS]
    if unknown:
        parser.error(f"unknown peer {unknown[0]!r} (known: {', '.join(PEERS)})")
    failed = 0
    for name in names:
        try:
            print(f"peer {name}: {PEERS[name]()}")
        except PeerUnavailable as error:
            print(f"error: {error}", file=sys.stderr)
            failed += 1
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
