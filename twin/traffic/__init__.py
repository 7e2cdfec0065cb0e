"""Co-simulated traffic: SUMO (through libsumo) moves vehicles and pedestrians on the build's own network.

Modules: ``frames`` (SUMO net <-> OpenDRIVE local coordinates), ``demand`` (seeded random routes),
``sumo`` (the SUMO runner and its per-step snapshot), ``bodies`` (pybullet kinematic bodies, ego contacts),
``publish`` (UDM layer-3/4 objects), ``behaviour`` (ego speed caps in traffic), ``hook`` (the twin session hook).
"""
