"""The ``twin drive`` session: loop, hooks, outputs and metrics."""
