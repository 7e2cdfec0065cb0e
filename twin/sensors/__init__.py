"""Simulated sensors of the twin's ego vehicle: GNSS, odometry/IMU, lidar and camera."""
