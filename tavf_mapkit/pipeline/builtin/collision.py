"""Stage "collision": the pybullet collision world (collision/world.json + tiles/*.obj) from the OpenDRIVE,
with the OSM input's buildings when the build started from OSM. See docs/collision-world.md."""

from __future__ import annotations

from tavf_mapkit.errors import InputError, StageError
from tavf_mapkit.pipeline.context import BuildContext
from tavf_mapkit.pipeline.stages import Stage, StageOutput, register_stage

DEFAULT_EPS = 0.05
DEFAULT_TILE = 100.0


@register_stage("collision")
class CollisionStage(Stage):
    inputs = ("xodr",)
    optional_inputs = ("source", "mesh")
    version = "6"  # 2: reuses the mesh stage's surface at the same eps; 3: curbs around junctions (reverted in 4);
    # 5: junction curbs along the connecting lanes' sides, clear of the swept path of a car on each driving lane;
    # 6: reuses the mesh stage's scene solids when they were made at the same eps from the same input
    description = "pybullet collision world: road surface, curbs, objects, signals, buildings (tiled OBJ)"

    def options(self, context: BuildContext) -> dict:
        section = context.section("collision")
        return {"eps": float(section.get("eps", DEFAULT_EPS)), "tile": float(section.get("tile", DEFAULT_TILE))}

    def run(self, context: BuildContext) -> StageOutput:
        from tavf_mapkit.opendrive import load_opendrive
        from tavf_mapkit.world import build_collision_world

        options = self.options(context)
        if not options["eps"] > 0 or not options["tile"] > 0:
            raise InputError("[collision] eps and tile must be positive numbers of metres")
        try:
            odr = load_opendrive(context.artifacts["xodr"])
        except InputError as error:
            raise StageError(f"netconvert's OpenDRIVE is unreadable: {error}") from None
        source = context.artifacts.get("source")
        osm_path = source if source is not None and context.input_kind == "osm" else None
        surface = _mesh_surface(context, options["eps"])
        scene = _mesh_solids(context, options["eps"], osm_path)
        world = build_collision_world(odr, context.folder, eps=options["eps"], osm_path=osm_path,
                                      tile=options["tile"], origin=_mesh_origin(context), surface=surface,
                                      scene=scene)
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


def _mesh_origin(context: BuildContext):
    """The exported meshes' origin (mesh/mesh.json), so the twin's visual and collision worlds coincide."""
    import json

    mesh = context.artifacts.get("mesh")
    if mesh is None:
        return None
    try:
        origin = json.loads((mesh / "mesh.json").read_text(encoding="utf-8"))["origin"]
        return [float(origin["x"]), float(origin["y"]), float(origin["z"])]
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _mesh_surface(context: BuildContext, eps: float):
    """The mesh stage's labelled road surface when it was made at the same eps (saves meshing twice)."""
    import json

    from tavf_mapkit.mesh.labelled import LabelledMesh

    mesh = context.artifacts.get("mesh")
    if mesh is None:
        return None
    try:
        saved = json.loads((mesh / "mesh.json").read_text(encoding="utf-8"))["surface"]
        if float(saved["eps"]) != eps:
            return None
        return LabelledMesh.load_npz(mesh / saved["file"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _mesh_solids(context: BuildContext, eps: float, osm_path):
    """The mesh stage's scene solids when they were made at the same eps with the same buildings input."""
    import json

    from tavf_mapkit.mesh.solids import SceneSolids

    mesh = context.artifacts.get("mesh")
    if mesh is None:
        return None
    try:
        saved = json.loads((mesh / "mesh.json").read_text(encoding="utf-8"))["scene_solids"]
        if float(saved["eps"]) != eps or saved["buildings_from"] != (None if osm_path is None else osm_path.name):
            return None
        return SceneSolids.load_npz(mesh / saved["file"])
    except (OSError, ValueError, KeyError, TypeError):
        return None
