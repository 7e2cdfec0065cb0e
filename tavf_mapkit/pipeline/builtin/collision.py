"""Stage "collision": the pybullet collision world (collision/world.json + tiles/*.obj) from the OpenDRIVE,
with the OSM input's buildings when the build started from OSM. See docs/collision-world.md."""

from __future__ import annotations

from pathlib import Path

from tavf_mapkit.pipeline.context import BuildContext
from tavf_mapkit.pipeline.stages import Stage, StageOutput, register_stage

DEFAULT_EPS = 0.05
DEFAULT_TILE = 100.0


@register_stage("collision")
class CollisionStage(Stage):
    makes = ("collision",)
    inputs = ("xodr",)
    optional_inputs = ("source", "mesh")
    version = "8"  # 2: reuses the mesh stage's surface at the same eps; 3: curbs around junctions (reverted in 4);
    # 5: junction curbs along the connecting lanes' sides, clear of the swept path of a car on each driving lane;
    # 6: reuses the mesh stage's scene solids when they were made at the same eps from the same input;
    # 7: a laneOffset step at a section boundary no longer bends the section's end; 8: tile by tile from the
    # mesh stage's labelled tiles, on the mesh grid (tiles centred on the origin, tilegrid.py)
    description = "pybullet collision world: road surface, curbs, objects, signals, buildings (tiled OBJ)"

    def options(self, context: BuildContext) -> dict:
        return {"eps": context.metres("collision", "eps", DEFAULT_EPS),
                "tile": context.metres("collision", "tile", DEFAULT_TILE)}

    def run(self, context: BuildContext) -> StageOutput:
        import tempfile

        from tavf_mapkit.world.build import UnreadableTile, build_collision_world_from_tiles

        options = self.options(context)
        osm_path = context.osm_source()
        meshed = _MeshStageOutput(context)
        # in this process a damaged tile shows while the world is built (each tile read once); Dask tasks would
        # fail on it far away, so their tiles are read through first
        labelled = meshed.labelled(options["eps"], options["tile"], osm_path, read=context.fanout is not None)
        world = None
        if labelled is not None:
            # the mesh stage's labelled tiles: the world is cut from exactly the meshes it exported
            try:
                world = build_collision_world_from_tiles(labelled, context.folder, progress=context.progress,
                                                         fanout=context.fanout)
            except UnreadableTile:
                labelled = None  # made again below, not trusted
        if world is None:
            from tavf_mapkit.mesh.tiled import LABELLED, write_tiled_mesh

            with tempfile.TemporaryDirectory(prefix=".collision-mesh-", dir=context.folder) as scratch:
                write_tiled_mesh(context.opendrive(), scratch, options["eps"], tile_size=options["tile"],
                                 osm_path=osm_path, preview=False, exports=False, origin=meshed.origin(),
                                 progress=context.progress)
                world = build_collision_world_from_tiles(Path(scratch) / LABELLED, context.folder,
                                                         progress=context.progress)
        totals = world["totals"]
        solids = world["solids"]
        if solids["skipped"]:
            context.note(f"collision: {len(solids['skipped'])} scene parts without a solid "
                         "(see collision/world.json)")
        facts = {"tiles": totals["tiles"], "bodies": totals["bodies"], "vertices": totals["vertices"],
                 "triangles": totals["triangles"], "origin": world["origin"],
                 "solids": {kind: solids[kind] for kind in ("curb", "object", "signal", "building")},
                 # what came from the mesh stage instead of being made again
                 "reused": ["surface", "solids"] if labelled is not None else []}
        return StageOutput(files={"collision": "collision"}, facts=facts)


class _MeshStageOutput:
    """What the mesh stage left for this one (mesh/mesh.json and its labelled tiles); None when absent,
    unreadable or made differently (other eps or tile size, other buildings input), so the stage makes it itself."""

    def __init__(self, context: BuildContext):
        import json

        self.folder = context.artifacts.get("mesh")
        self.record = {}
        if self.folder is not None:
            try:
                self.record = json.loads((self.folder / "mesh.json").read_text(encoding="utf-8"))
            except (OSError, ValueError):
                pass

    def origin(self):
        """The exported meshes' origin, so the twin's visual and collision worlds coincide."""
        try:
            origin = self.record["origin"]
            return [float(origin["x"]), float(origin["y"]), float(origin["z"])]
        except (KeyError, TypeError, ValueError):
            return None

    def labelled(self, eps: float, tile: float, osm_path, read: bool = True) -> Path | None:
        """mesh/labelled, when it was made at ``eps`` on tiles of ``tile`` metres, with solids, from the same
        buildings input, and every file it lists is there and readable (``read`` off: there, as files; the
        caller reads them and makes the world anew if one is unreadable)."""
        import os

        from tavf_mapkit.mesh.tiled import read_labelled_index
        from tavf_mapkit.npzfile import read_npz
        from tavf_mapkit.world.build import TILE_READ_ERRORS

        try:
            saved = self.record["labelled"]
            if (float(saved["eps"]) != eps or float(saved["tile_size"]) != tile or saved["solids"] is not True
                    or saved["buildings_from"] != (None if osm_path is None else osm_path.name)):
                return None
            folder = self.folder / saved["folder"]
            index = read_labelled_index(folder)
            if float(index["eps"]) != eps or float(index["tile_size"]) != tile:
                return None
            if not read:
                # one listing of the folder, not a stat per tile (a region has tens of thousands)
                files = {entry.name for entry in os.scandir(folder) if entry.is_file()}
                return folder if all(f"{name}.npz" in files for name in index["tiles"]) else None
            for name in index["tiles"]:
                # a damaged file is made again, not trusted: BadZipFile (zip), EOFError / ValueError (arrays)
                read_npz(folder / f"{name}.npz")
            return folder
        except TILE_READ_ERRORS:
            return None
