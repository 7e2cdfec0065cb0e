"""The simulated world: a build folder opened for driving, and the pybullet client with its collision world."""
