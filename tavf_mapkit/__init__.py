"""tavf-mapkit: real city map data -> OpenDRIVE, meshes and a collision world for driving simulation."""

__version__ = "0.1.0"
