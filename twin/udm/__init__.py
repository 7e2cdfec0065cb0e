"""The Urban Dynamic Map: a local HTTP service of map objects near the car, and the twin's client for it.

model   -- UdmObject, its GeoJSON form and validation; WGS84 boxes and distances
store   -- the Store interface and SqliteRtreeStore (SQLite + R*Tree)
server  -- the starlette app (create_app) and uvicorn runners
seed    -- load a build folder's signs and signals (seed_from_build, SEED_SOURCES)
client  -- UdmClient (non-blocking queries from the simulation loop) and LatencyLog
loadgen -- a simulated fleet for latency under load (twin udm bench-load)

The API is described in docs/udm-api.md.
"""
