"""drive.png: the drive over the map (lane centres grey, the ego's path coloured by speed, the trace black)."""

from __future__ import annotations

from pathlib import Path


def plot_drive(path: Path, session, recorder, margin: float = 60.0) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x, y, speed = recorder.column("x"), recorder.column("y"), recorder.column("speed")
    west, east = float(x.min()) - margin, float(x.max()) + margin
    south, north = float(y.min()) - margin, float(y.max()) + margin
    centre, driving = lane_centres_in(session.odr, west, south, east, north)
    figure, axes = plt.subplots(figsize=(8, 8), dpi=100)
    axes.scatter(centre[driving, 0], centre[driving, 1], s=0.3, c="0.7", linewidths=0)
    axes.scatter(centre[~driving, 0], centre[~driving, 1], s=0.3, c="0.85", linewidths=0)
    route = session.route
    if route is not None:
        fx, fy = route.matched_xy
        axes.scatter(fx, fy, s=4, c="k", label="recorded fixes (matched)")
    points = axes.scatter(x, y, c=speed * 3.6, s=1.5, cmap="viridis", linewidths=0)
    figure.colorbar(points, ax=axes, label="speed (km/h)", shrink=0.7)
    axes.plot(x[:1], y[:1], "o", color="tab:green", label="start")
    axes.plot(x[-1:], y[-1:], "s", color="tab:red", label="end")
    collisions = [c for c in session.fleet.counters.collisions if c.vehicle == 0]
    if collisions:
        axes.scatter([c.x for c in collisions], [c.y for c in collisions], marker="x", c="red", s=40,
                     label="collisions")
    axes.set_xlim(west, east)
    axes.set_ylim(south, north)
    axes.set_aspect("equal")
    axes.set_xlabel("x east (m, map frame)")
    axes.set_ylabel("y north (m)")
    config = session.drive_config
    kind = f"route {Path(config.route).name}" if config.route else "random route"
    axes.set_title(f"twin drive {session.build.name}: {kind}, seed {config.seed}, {recorder.n * session.dt:.0f} s")
    axes.legend(loc="upper right", fontsize=8)
    figure.tight_layout()
    figure.savefig(path)
    plt.close(figure)


def lane_centres_in(odr, west: float, south: float, east: float, north: float, step: float = 2.0,
                    chunk_points: int = 500_000):
    """(lane centre points every ``step`` m inside the box, whether each is on a driving lane), in map order.
    Sampled a part of the map at a time: a region's lanes at once are more points than one allocation may hold
    (Columbus: 4.3 million at 2 m, refused), and all but the drive's surroundings are left out anyway."""
    import numpy as np

    from tavf_mapkit.opendrive.sampling import sample_lane_chunks

    centres, kinds = [], []
    for sampling in sample_lane_chunks(odr, step, chunk_points):
        centre = sampling.center_points(with_height=False)
        inside = (centre[:, 0] > west) & (centre[:, 0] < east) & (centre[:, 1] > south) & (centre[:, 1] < north)
        centres.append(centre[inside])
        kinds.append(sampling.lane_type[inside] == "driving")
    if not centres:  # a map without lanes
        return np.zeros((0, 3)), np.zeros(0, dtype=bool)
    return np.concatenate(centres), np.concatenate(kinds)
