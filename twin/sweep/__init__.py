"""``twin sweep``: many seeded ``twin drive`` runs of one build, on this machine or a Dask cluster, gathered into
one table (``sweep.csv``, ``sweep.json``) with the worst runs named.

- ``plan``: the seeds and the drive options every run shares;
- ``runs``: one run = one ``twin drive`` in its own process (libsumo allows one simulation per process), with a
  deadline; on a cluster the build folder reaches the workers as one archive (content-addressed, unpacked once
  per worker), so no shared filesystem is needed;
- ``table``: the per-run rows, read from each run's own metrics.json (and udm_latency.csv for p99), and the
  summary.
"""
