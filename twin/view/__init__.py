"""``twin drive --view``: the running drive on the page of ``mapkit view`` (hook.py; the server is
tavf_mapkit/view/live.py, in a child process)."""
