"""The pybullet collision world of a build: ``build_collision_world`` writes collision/, ``load`` puts it into
a pybullet client and returns the body ids, ``TileStream`` keeps only the tiles near moving points in it
(see docs/collision-world.md)."""

from tavf_mapkit.world.bodies import Body, WorldBodies
from tavf_mapkit.world.build import build_collision_world
from tavf_mapkit.world.loader import load, read_world
from tavf_mapkit.world.stream import TileStream

__all__ = ["Body", "TileStream", "WorldBodies", "build_collision_world", "load", "read_world"]
