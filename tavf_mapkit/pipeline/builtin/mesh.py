"""Stage "mesh": road surface, junction surfaces, road marks and scene solids as tiled glTF (or OBJ) in mesh/,
with mesh/mesh.json, a top-view preview that is also copied to report/mesh_preview.png, and the labelled
surface and solids per tile (mesh/labelled/) the collision stage reuses. Made tile by tile, in memory bounded by
the tile, not the map (mesh/tiled.py). See docs/mesh.md."""

from __future__ import annotations

import shutil

from tavf_mapkit.errors import InputError
from tavf_mapkit.pipeline.context import BuildContext
from tavf_mapkit.pipeline.stages import Stage, StageOutput, register_stage


@register_stage("mesh")
class MeshStage(Stage):
    makes = ("mesh", "mesh_preview")
    inputs = ("xodr",)
    optional_inputs = ("source",)
    version = "8"  # 2: also writes mesh/surface.npz; 3: curbs around junctions (reverted in 4); 5: junction curbs
    # along the connecting lanes' sides, clear of the swept path of a car following each driving lane;
    # 6: also writes mesh/solids.npz; 7: a laneOffset step at a section boundary no longer bends the section's end;
    # 8: tiled (mesh/labelled/ instead of surface.npz and solids.npz; faces in canonical unit order; junction
    # surfaces and curbs per junction cluster)
    description = "road surface, junctions and road marks (and scene solids) as tiled glTF + preview"

    def options(self, context: BuildContext) -> dict:
        section = context.section("mesh")
        eps, tile = context.metres("mesh", "eps", 0.05), context.metres("mesh", "tile", 100.0)
        fmt = str(section.get("format", "glb")).lower()
        if fmt not in ("glb", "obj"):
            raise InputError(f"[mesh] format must be glb or obj, not {fmt!r}")
        return {"eps": eps, "tile": tile, "format": fmt, "solids": bool(section.get("solids", True))}

    def run(self, context: BuildContext) -> StageOutput:
        from tavf_mapkit.mesh.folder import write_mesh_folder
        from tavf_mapkit.pipeline.builtin.stage_map import stage_map

        options = self.options(context)
        odr = stage_map(context)  # kept for the check stage when small (stage_map.py)
        osm_path = context.osm_source()
        folder = context.output_path("mesh/mesh.json").parent
        summary = write_mesh_folder(odr, folder, options["eps"], options["format"], options["tile"],
                                    osm_path=osm_path, solids=options["solids"], progress=context.progress,
                                    fanout=context.fanout)  # tasks get this map, pickled (mesh.remote)
        shutil.copyfile(folder / "preview.png", context.output_path("report/mesh_preview.png"))
        triangles = summary["triangles"]
        context.note(f"mesh: {triangles['lanes'] + triangles['junctions']} surface + {triangles['marks']} mark"
                     f" + {triangles['solids']} solid triangles in {len(summary['tiles'])} tiles")
        facts = {
            "eps": options["eps"], "format": options["format"], "tiles": len(summary["tiles"]),
            "triangles": triangles, "junctions": summary["junctions"],
            "max_deviation_m": summary["deviation"]["max_m"],
            "origin": summary["origin"], "solids": summary["solids"],
        }
        return StageOutput(files={"mesh": "mesh", "mesh_preview": "report/mesh_preview.png"}, facts=facts)
