"""Controllers: CARLA-style lateral/longitudinal PID and pure pursuit, vectorised over vehicles."""
