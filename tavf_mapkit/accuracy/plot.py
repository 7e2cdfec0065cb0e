"""PNG overlays: a build's lanes coloured by their distance to a reference, or GNSS fixes by match distance."""

from __future__ import annotations

import io

import numpy as np

from tavf_mapkit.fileutil import write_bytes_atomic

ERROR_SCALE_M = 5.0


def _figure(title: str):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(figsize=(9, 8), dpi=110)
    axes.set_aspect("equal")
    axes.set_title(title, fontsize=10)
    axes.set_xlabel("east (m)")
    axes.set_ylabel("north (m)")
    return plt, figure, axes


def _save(plt, figure, path) -> None:
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", bbox_inches="tight")
    plt.close(figure)
    write_bytes_atomic(path, buffer.getvalue())


def plot_comparison(comparison, path) -> None:
    """Reference lanes in grey, build lanes coloured by distance to the reference (0..5 m and beyond)."""
    plt, figure, axes = _figure(
        f"{comparison.report['build']} vs {comparison.report['reference']}\n"
        "build lanes by distance to the reference (m); reference in grey; outside the overlap: light")
    reference, build = comparison.reference.lanes, comparison.build.lanes
    axes.scatter(reference.x, reference.y, s=0.3, c="0.55", linewidths=0, rasterized=True)
    outside = ~comparison.build_in
    axes.scatter(build.x[outside], build.y[outside], s=0.3, c="#c9d7ea", linewidths=0, rasterized=True)
    inside = comparison.build_in
    points = axes.scatter(build.x[inside], build.y[inside], s=0.6, c=comparison.build_offset[inside],
                          cmap="turbo", vmin=0.0, vmax=ERROR_SCALE_M, linewidths=0, rasterized=True)
    figure.colorbar(points, ax=axes, shrink=0.7, label="distance to reference lane (m)")
    _save(plt, figure, path)


def plot_match(result, graph, path, title: str = "") -> None:
    """Lane centre lines in grey, GNSS fixes coloured by distance to their matched lane, unmatched in black."""
    plt, figure, axes = _figure(title or "GNSS fixes by distance to the matched lane (m); unmatched: x")
    from tavf_mapkit.lanegraph import LaneIndex

    index = LaneIndex(graph)
    axes.scatter(index.xy[:, 0], index.xy[:, 1], s=0.2, c="0.6", linewidths=0, rasterized=True)
    route = set(result.lane_route)
    on_route = np.isin(np.arange(len(index.keys)), [index.keys.index(k) for k in route]) if route else None
    if on_route is not None:
        mask = on_route[index.node]
        axes.scatter(index.xy[mask, 0], index.xy[mask, 1], s=0.5, c="#1f77b4", linewidths=0, rasterized=True)
    matched = result.matched
    points = axes.scatter(result.x[matched], result.y[matched], s=6, c=result.distance_m[matched], cmap="turbo",
                          vmin=0.0, vmax=3 * ERROR_SCALE_M, linewidths=0)
    axes.scatter(result.x[~matched], result.y[~matched], s=8, c="k", marker="x", linewidths=0.6)
    figure.colorbar(points, ax=axes, shrink=0.7, label="distance to matched lane (m)")
    _save(plt, figure, path)
