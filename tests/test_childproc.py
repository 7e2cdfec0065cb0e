"""The twin's helper processes (twin/childproc.py, behind the UDM client process and the traffic publisher
process): a child that cannot start says why in one line, and nothing waits on a stuck child past its deadline."""

from __future__ import annotations

import asyncio
import signal
import time

import pytest
from starlette.applications import Starlette
from starlette.responses import JSONResponse
from starlette.routing import Route

from twin.traffic.publish_process import TrafficPublisherProcess
from twin.udm.process_client import UdmProcessClient
from twin.udm.server import ServerThread

HAMBURG = (53.55, 9.99)


def test_a_child_that_cannot_start_says_why_in_one_line(tmp_path):
    missing = tmp_path / "missing.net.xml"
    started = time.monotonic()
    with pytest.raises(RuntimeError) as failed:
        TrafficPublisherProcess("http://127.0.0.1:9", "token", missing, tmp_path / "missing.xodr", None,
                                period_sim_s=0.1)
    message = str(failed.value)
    assert message.startswith("the traffic publisher process did not start: ") and "\n" not in message
    assert str(missing) in message and time.monotonic() - started < 20.0


def test_a_stuck_child_is_stopped_within_the_deadline():
    """The child is inside a 4 s request when it is asked to flush and close: flush gives up after its deadline,
    close after its own, and the child is killed rather than waited for; every query is accounted for."""
    async def sleepy(request):
        await asyncio.sleep(5.0)
        return JSONResponse({"type": "FeatureCollection", "features": []})

    with ServerThread(Starlette(routes=[Route("/{path:path}", sleepy)])) as server:
        client = UdmProcessClient(server.url, timeout_s=4.0, max_retries=0)
        assert client.submit(*HAMBURG, frame=1)
        time.sleep(0.2)  # the child has taken the query and is waiting for the server
        flushing = time.monotonic()
        assert client.flush(0.3) is False
        assert time.monotonic() - flushing < 1.5  # its deadline plus the one second the child gets first
        closing = time.monotonic()
        client.close(timeout_s=0.5)
        assert time.monotonic() - closing < 2.5  # < the 3.7 s the request still had to run
        assert client._child.process.returncode == -signal.SIGKILL
        assert not client.submit(*HAMBURG, frame=2)  # closed: refused, not raised
        stats = client.stats()
    assert stats.submitted == 1 and stats.abandoned == 1 and stats.ok == 0
