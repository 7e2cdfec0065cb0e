"""OpenStreetMap input: cut an area out of an OSM file with osmium and count what it holds."""
