"""See a build and its drives in the browser: ``mapkit view BUILD [RUN ...]`` and the build's report page.

- ``mapdata``: the build's map as WGS84 GeoJSON layers (lanes, road marks, signals, objects, junction
  outlines, validation findings, repairs, the GNSS trace and its matched path), computed with the project's
  own evaluator (``opendrive.layers``, ``opendrive.borders`` through ``Road.lane_borders``, the mesh's
  junction footprints) -- never a second derivation of lane borders;
- ``scene``: what the 3D view loads (the glTF mesh tiles and the collision world's OBJ tiles);
- ``runs``: a ``twin drive`` output folder as replay data (ego, SUMO vehicles and pedestrians, UDM objects);
- ``server``: the starlette app ``mapkit view`` serves on 127.0.0.1;
- ``page``: the HTML pages -- the live page of the server and the static report (data embedded, no server).

The JavaScript it needs (Leaflet, three.js) is vendored under ``static/vendor`` (docs/view.md says where it
came from): the page works without internet.
"""
