"""Stage "collision": the pybullet collision world (collision/world.json + tiles/*.obj) from the OpenDRIVE,
with the OSM input's buildings when the build started from OSM. See docs/collision-world.md."""

from __future__ import annotations

from tavf_mapkit.pipeline.context import BuildContext
from tavf_mapkit.pipeline.stages import Stage, StageOutput, register_stage

DEFAULT_EPS = 0.05
DEFAULT_TILE = 100.0


@register_stage("collision")
class CollisionStage(Stage):
    inputs = ("xodr",)
    optional_inputs = ("source", "mesh")
    version = "7"  # 2: reuses the mesh stage's surface at the same eps; 3: curbs around junctions (reverted in 4);
    # 5: junction curbs along the connecting lanes' sides, clear of the swept path of a car on each driving lane;
    # 6: reuses the mesh stage's scene solids when they were made at the same eps from the same input;
    # 7: a laneOffset step at a section boundary no longer bends the section's end
    description = "pybullet collision world: road surface, curbs, objects, signals, buildings (tiled OBJ)"

    def options(self, context: BuildContext) -> dict:
        return {"eps": context.metres("collision", "eps", DEFAULT_EPS),
                "tile": context.metres("collision", "tile", DEFAULT_TILE)}

    def run(self, context: BuildContext) -> StageOutput:
        from tavf_mapkit.world import build_collision_world

        options = self.options(context)
        odr = context.opendrive()
        osm_path = context.osm_source()
        meshed = _MeshStageOutput(context)
        surface = meshed.surface(options["eps"])
        scene = meshed.solids(options["eps"], osm_path)
        world = build_collision_world(odr, context.folder, eps=options["eps"], osm_path=osm_path,
                                      tile=options["tile"], origin=meshed.origin(), surface=surface, scene=scene)
        totals = world["totals"]
        solids = world["solids"]
        if solids["skipped"]:
            context.note(f"collision: {len(solids['skipped'])} scene parts without a solid "
                         "(see collision/world.json)")
        facts = {"tiles": totals["tiles"], "bodies": totals["bodies"], "vertices": totals["vertices"],
                 "triangles": totals["triangles"], "origin": world["origin"],
                 "solids": {kind: solids[kind] for kind in ("curb", "object", "signal", "building")},
                 # what came from the mesh stage instead of being made again
                 "reused": [name for name, part in (("surface", surface), ("solids", scene)) if part is not None]}
        return StageOutput(files={"collision": "collision"}, facts=facts)


class _MeshStageOutput:
    """What the mesh stage left for this one (mesh/mesh.json and its files); every part None when absent,
    unreadable or made differently (other eps, other buildings input), so the stage makes it itself."""

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

    def surface(self, eps: float):
        """The labelled road surface, when it was made at ``eps`` (saves meshing twice)."""
        from tavf_mapkit.mesh.labelled import LabelledMesh

        return self._load("surface", LabelledMesh.load_npz, eps=eps)

    def solids(self, eps: float, osm_path):
        """The scene solids, when they were made at ``eps`` with the same buildings input."""
        from tavf_mapkit.mesh.solids import SceneSolids

        return self._load("scene_solids", SceneSolids.load_npz, eps=eps,
                          buildings_from=None if osm_path is None else osm_path.name)

    def _load(self, key: str, load, eps: float, **same):
        import zipfile

        try:
            saved = self.record[key]
            if float(saved["eps"]) != eps or any(saved[name] != value for name, value in same.items()):
                return None
            return load(self.folder / saved["file"])
        # a damaged file is made again, not trusted: BadZipFile (zip), EOFError / ValueError (arrays)
        except (OSError, ValueError, KeyError, TypeError, IndexError, EOFError, zipfile.BadZipFile):
            return None
