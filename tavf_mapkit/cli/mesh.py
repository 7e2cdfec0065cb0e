"""``mapkit mesh``: road meshes of an OpenDRIVE file as tiled glTF or OBJ, with mesh.json and a preview."""

from __future__ import annotations

import json
from pathlib import Path

import click

from tavf_mapkit.cli.options import json_option, xodr_argument


@click.command()
@xodr_argument()
@click.option("-o", "--output", "output", required=True, type=click.Path(file_okay=False, path_type=Path),
              metavar="FOLDER", help="Folder to write (replaced atomically; must be new, empty or an earlier "
                                     "mesh folder).")
@click.option("--eps", type=click.FloatRange(min=0.001, max=10.0), default=0.05, show_default=True,
              help="Largest distance in metres between the mesh and the exact OpenDRIVE surface.")
@click.option("--format", "fmt", type=click.Choice(["glb", "obj"]), default="glb", show_default=True,
              help="glTF binary (materials, +Y up) or OBJ+MTL.")
@click.option("--tile", type=click.FloatRange(min=1.0), default=100.0, show_default=True,
              help="Tile size in metres (one file per tile).")
@click.option("--osm", "osm_path", type=click.Path(dir_okay=False, exists=True, path_type=Path), default=None,
              help="OSM file the map was made from: its buildings join the scene solids.")
@click.option("--solids/--no-solids", default=True, show_default=True,
              help="Also export curbs, objects, signals (and buildings) as solids.")
@click.option("--preview/--no-preview", default=True, show_default=True, help="Write preview.png (top view).")
@json_option
def mesh(xodr: str, output: Path, eps: float, fmt: str, tile: float, osm_path: Path | None, solids: bool,
         preview: bool, as_json: bool) -> None:
    """Mesh an OpenDRIVE map: lanes, junction surfaces, road marks (and scene solids).

    \b
    $ mapkit mesh build/tavf/tavf.xodr -o out/tavf-mesh
    $ mapkit mesh map.xodr -o out/mesh --eps 0.1 --format obj --tile 250
    $ mapkit mesh map.xodr -o out/mesh --json | jq .triangles

    Every lane is sampled adaptively along s so that no point of the mesh is further than --eps from
    the exact surface (geometry, elevation, superelevation, lane offset, widths); junctions get one
    non-overlapping surface each. The folder holds tiles/tile_I_J.glb (or .obj + materials.mtl),
    mesh.json (origin, axes, tiles, triangle counts, measured deviation) and preview.png. Files are
    recentred on mesh.json's origin and use glTF's +Y-up axes: (X, Y, Z) = (x - ox, z - oz, -(y - oy)).
    """
    from tavf_mapkit.mesh.folder import replace_folder, write_mesh_folder
    from tavf_mapkit.opendrive.snapshot import load_build_map  # the build's snapshot when the file has one

    odr = load_build_map(xodr)
    summary = replace_folder(output, lambda folder: write_mesh_folder(
        odr, folder, eps, fmt, tile, osm_path=osm_path, solids=solids, preview=preview))
    if as_json:
        click.echo(json.dumps({key: summary[key] for key in summary if key != "tiles"} |
                              {"tiles": len(summary["tiles"]), "folder": str(output)}, indent=2))
        return
    counts = summary["triangles"]
    origin = summary["origin"]
    click.echo(f"{output}: {len(summary['tiles'])} {fmt} tiles of {summary['tile_size']:g} m")
    click.echo(f"  triangles  lanes {counts['lanes']}, junctions {counts['junctions']}, curb faces "
               f"{counts['curb_faces']}, marks {counts['marks']}, solids {counts['solids']}")
    click.echo(f"  deviation  <= {summary['deviation']['max_m']:.4f} m (eps {eps:g} m)")
    click.echo(f"  origin     x {origin['x']:.1f}, y {origin['y']:.1f}, z {origin['z']:.1f} (OpenDRIVE local)")
