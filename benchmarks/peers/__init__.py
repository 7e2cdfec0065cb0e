"""Independent oracles for OpenDRIVE files, shared by the benchmarks and the slow tests (not the package).

Each peer is a program we did not write, kept out of the project's dependencies and cached, git-ignored, under
``benchmarks/.peers/`` (or ``$TAVF_PEERS_DIR``):

- ``libopendrive``: the C++ evaluator of ``../shared/tools/libopendrive`` (libOpenDRIVE), compiled by its
  ``build.sh``: every lane border of a file in the reference CSV format -- the exact oracle for lane borders;
- ``carla_map``: CARLA 0.9.16's client-side map (PyPI ``carla``, its own venv): waypoints on lane centres;
- ``asam_qc``: ASAM's quality checker for OpenDRIVE (PyPI ``asam-qc-opendrive``, its own venv: it pins
  numpy < 2): issues by checker.

``python -m benchmarks.peers.install`` (from the checkout) makes all three; the benchmarks make a missing one
on first use, the tests never do: they skip with the reason, or fail under ``CI=true``, where ``.ci/run``
installs them first. ``borders.py`` joins a peer's lane borders with ours at the same (road, section, lane,
s). """

from __future__ import annotations

from .cache import PEERS_DIR, PeerUnavailable

__all__ = ["PEERS_DIR", "PeerUnavailable"]
