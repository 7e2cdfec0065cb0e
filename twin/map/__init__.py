"""The road map as the car sees it: lane centre lines and waypoints over the lane graph."""
