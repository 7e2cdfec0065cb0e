"""The ego vehicle: Tesla Model S parameters, a vectorised dynamic bicycle model, its pybullet body."""
