"""The digital-twin runtime: drive a simulated vehicle through a mapkit build while it talks to a UDM."""

__version__ = "0.1.0"
