"""Route planning (global A*, random never-dead-ending routes, recorded traces) and the local planner.

The split follows CARLA's navigation agents: a route planner yields lanes, the path buffer turns them into a
dense polyline per vehicle, the local planner picks the target point and speed, a controller steers.
"""
