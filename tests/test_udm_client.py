"""UdmClient against the real server and against deliberately broken ones: it counts, it never raises."""

from __future__ import annotations

import asyncio
import csv
import itertools
import math
import os
import socket
import subprocess
import sys
import time

import pytest
from starlette.applications import Starlette
from starlette.responses import JSONResponse, Response, StreamingResponse
from starlette.routing import Route

from twin.udm.client import (
    HTTP_5XX,
    INVALID_FIX,
    MALFORMED,
    OK,
    TIMEOUT,
    UNREACHABLE,
    LatencyLog,
    UdmClient,
    run_queue_wait_s,
    server_timing_s,
)
from twin.udm.loadgen import LoadPlan, is_loopback_url, run_load
from twin.udm.model import UdmObject, square_around
from twin.udm.server import ServerThread, create_app
from twin.udm.store import SqliteRtreeStore

HAMBURG = (53.55, 9.99)


def wait_for(client: UdmClient, count: int, timeout_s: float = 5.0) -> list:
    responses = []
    deadline = time.monotonic() + timeout_s
    while len(responses) < count and time.monotonic() < deadline:
        responses += client.poll()
        time.sleep(0.005)
    return responses


@pytest.fixture(scope="module")
def udm():
    store = SqliteRtreeStore()
    store.upsert([
        UdmObject(id=f"sign-{i}", layer=2 if i % 2 else 4, type="traffic_sign" if i % 3 else "vehicle",
                  lat=HAMBURG[0] + 0.0001 * (i - 10), lon=HAMBURG[1] + 0.0001 * (i - 10))
        for i in range(21)
    ])
    with ServerThread(create_app(store, "token")) as server:
        yield server.url, store
    store.close()


def fault_server(handler):
    """A one-route server standing in for a broken UDM; answers every path with ``handler``."""
    app = Starlette(routes=[Route("/{path:path}", handler)])
    return ServerThread(app)


def closed_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def test_answers_match_the_store_and_carry_both_latencies(udm, tmp_path):
    url, store = udm
    with UdmClient(url) as client:
        t_publish = time.monotonic()
        assert client.submit(*HAMBURG, side_m=200.0, frame=7, t_publish=t_publish)
        (response,) = wait_for(client, 1)
        stats = client.stats()
    assert response.status == OK and response.frame == 7 and response.attempts == 1
    expected = {o.id for o in store.in_bbox(square_around(*HAMBURG, 200.0))}
    assert expected and {o.id for o in response.objects} == expected
    assert 0 < response.client_latency_s <= response.loop_latency_s < 5.0
    assert response.t_publish == t_publish <= response.t_sent <= response.t_received
    assert (stats.submitted, stats.ok, stats.requests, stats.error_count) == (1, 1, 1, 0)

    with LatencyLog(tmp_path) as log:
        log.write(response)
    rows = list(csv.DictReader((tmp_path / "udm_latency.csv").open()))
    assert list(rows[0]) == list(LatencyLog.COLUMNS)
    assert rows[0]["frame"] == "7" and rows[0]["status"] == "ok"
    assert int(rows[0]["n_objects"]) == len(expected)
    assert math.isclose(float(rows[0]["client_latency_s"]), response.client_latency_s, abs_tol=1e-6)
    assert math.isclose(float(rows[0]["server_s"]), response.server_s, abs_tol=1e-6)


def test_latency_is_split_into_the_servers_time_and_the_clients_wait(udm):
    url, _ = udm
    with UdmClient(url) as client:
        for frame in range(5):
            client.submit(*HAMBURG, side_m=200.0, frame=frame)
        responses = wait_for(client, 5)
    assert [response.status for response in responses] == [OK] * 5
    for response in responses:
        # the server's own time (its Server-Timing) is a part of what the client measured around the request
        assert 0 < response.server_s < response.client_latency_s
        assert response.wait_s is not None and response.wait_s >= 0  # Linux reports the run-queue wait


def test_server_timing_header_parsing():
    assert server_timing_s("app;dur=0.412") == pytest.approx(0.000412)
    assert server_timing_s("db;dur=3, app;desc=\"handler\";dur=2.5") == pytest.approx(0.0025)
    assert server_timing_s("") is None
    assert server_timing_s("db;dur=3") is None  # no entry of ours
    assert server_timing_s("app;dur=fast") is None
    assert server_timing_s("app;dur=-1") is None
    assert server_timing_s("app;dur=nan") is None


def test_run_queue_wait_only_grows():
    first = run_queue_wait_s()
    deadline = time.perf_counter() + 0.05
    while time.perf_counter() < deadline:  # be runnable for a while
        pass
    second = run_queue_wait_s()
    assert first is not None and second is not None  # Linux keeps schedstat for every thread
    assert 0 <= first <= second


def test_layer_and_type_filters_reach_the_server(udm):
    url, _ = udm
    with UdmClient(url, layers=(4,), types=("vehicle",)) as client:
        client.submit(*HAMBURG, side_m=500.0, frame=1)
        (response,) = wait_for(client, 1)
    assert response.ok and response.objects
    assert all(o.layer == 4 and o.type == "vehicle" for o in response.objects)


def test_many_frames_in_order_with_a_full_queue_dropping_the_oldest(udm):
    url, _ = udm
    with UdmClient(url, queue_size=4) as client:
        for frame in range(200):
            client.submit(*HAMBURG, frame=frame)
        assert client.flush(10.0)
        responses = client.poll()
        stats = client.stats()
    frames = [r.frame for r in responses]
    assert frames == sorted(frames) and frames[-1] == 199  # the newest query is never the one dropped
    assert stats.dropped == 200 - len(responses) and stats.submitted == 200
    assert all(r.ok for r in responses)


def test_unreachable_server_is_counted_and_retried_without_raising():
    with UdmClient(f"http://127.0.0.1:{closed_port()}", max_retries=2, backoff_s=0.01) as client:
        started = time.perf_counter()
        assert client.submit(*HAMBURG, frame=1)
        assert time.perf_counter() - started < 0.01
        (response,) = wait_for(client, 1)
        stats = client.stats()
    assert response.status == UNREACHABLE and response.attempts == 3 and response.objects == ()
    assert "ConnectError" in response.error
    assert stats.errors == {UNREACHABLE: 1} and stats.retries == 2 and stats.requests == 3


def test_slow_server_times_out_while_submit_never_blocks():
    async def sleepy(request):
        await asyncio.sleep(5.0)
        return JSONResponse({"type": "FeatureCollection", "features": []})

    with fault_server(sleepy) as server:
        client = UdmClient(server.url, timeout_s=0.2, max_retries=0, queue_size=4)
        submit_times = []
        for frame in range(30):  # the worker is stuck in the first request meanwhile
            started = time.perf_counter()
            client.submit(*HAMBURG, frame=frame)
            submit_times.append(time.perf_counter() - started)
        assert max(submit_times) < 0.01
        responses = wait_for(client, 2, timeout_s=3.0)
        closing = time.perf_counter()
        client.close()
        assert time.perf_counter() - closing < 1.0
        stats = client.stats()
    assert responses and all(r.status == TIMEOUT for r in responses)
    assert all(0.2 <= r.client_latency_s < 1.0 for r in responses)
    assert stats.errors[TIMEOUT] >= 2 and stats.dropped >= 30 - 4 - 1
    assert not client._thread.is_alive()


def test_http_500_is_retried_a_bounded_number_of_times():
    hits = []

    async def broken(request):
        hits.append(time.monotonic())
        return Response("database on fire", status_code=500)

    with fault_server(broken) as server, UdmClient(server.url, max_retries=3, backoff_s=0.02,
                                                   max_backoff_s=0.05) as client:
        client.submit(*HAMBURG, frame=1)
        (response,) = wait_for(client, 1)
        stats = client.stats()
    assert response.status == HTTP_5XX and response.http_status == 500 and response.attempts == 4
    assert len(hits) == 4 and stats.errors == {HTTP_5XX: 1} and stats.retries == 3
    gaps = [later - earlier for earlier, later in itertools.pairwise(hits)]
    assert gaps[0] >= 0.02 and gaps[-1] >= 0.05 * 0.9  # backoff grew and was capped


@pytest.mark.parametrize("body", [b"{this is not json", b'{"hello": "world"}',
                                  b'{"type": "FeatureCollection", "features": [{"type": "Feature"}]}'])
def test_malformed_answers_are_counted_not_retried(body):
    hits = []

    async def garbled(request):
        hits.append(1)
        return Response(body, media_type="application/json")

    with fault_server(garbled) as server, UdmClient(server.url, max_retries=3) as client:
        client.submit(*HAMBURG, frame=1)
        (response,) = wait_for(client, 1)
    assert response.status == MALFORMED and response.objects == () and len(hits) == 1
    assert client.stats().errors == {MALFORMED: 1}


def test_bad_fixes_and_use_after_close_do_not_raise(udm):
    url, _ = udm
    client = UdmClient(url)
    assert client.submit(math.nan, 9.99, frame=1) is False
    assert client.submit(53.55, math.inf, frame=2) is False
    responses = client.poll()
    assert [r.status for r in responses] == [INVALID_FIX, INVALID_FIX]
    client.close()
    assert client.submit(*HAMBURG, frame=3) is False
    assert client.poll() == []
    client.close()  # closing twice is harmless


def test_load_generator_reports_latency_against_the_real_server(udm):
    url, _ = udm
    report = run_load(LoadPlan(url=url, vehicles=5, rate_hz=20.0, duration_s=0.5, area_radius_m=150.0))
    assert report["errors"] == 0 and report["ok"] == report["requests"]
    assert 0 < report["requests"] <= 5 * 20 * 0.5 + 5  # bounded by vehicles x rate x duration (+ phase)
    latency = report["latency_ms"]
    assert 0 < latency["p50"] <= latency["p95"] <= latency["max"]
    assert report["objects_per_response"] > 0


def test_load_generator_counts_unreachable_and_only_trusts_loopback():
    report = run_load(LoadPlan(url=f"http://127.0.0.1:{closed_port()}", vehicles=2, rate_hz=10.0,
                               duration_s=0.3))
    assert report["ok"] == 0 and report["errors"] == report["requests"] > 0
    assert set(report["errors_by_kind"]) == {UNREACHABLE}
    assert is_loopback_url("http://127.0.0.1:8765") and is_loopback_url("http://localhost:1")
    assert is_loopback_url("http://[::1]:80")
    assert not is_loopback_url("http://192.168.1.10:8765") and not is_loopback_url("http://udm.example.com")
    with pytest.raises(ValueError):
        LoadPlan(url="http://127.0.0.1:1", vehicles=10_000).check()


def test_load_generator_reads_chunked_answers_and_counts_server_faults():
    async def chunked(request):
        async def parts():
            yield b'{"type": "FeatureCollection", '
            yield b'"features": [{"type": "Feature"}, {"type": "Feature"}]}'
        return StreamingResponse(parts(), media_type="application/geo+json")

    async def failing(request):
        return Response("no", status_code=503)

    async def sleepy(request):
        await asyncio.sleep(2.0)
        return Response("{}")

    plan = {"vehicles": 2, "rate_hz": 10.0, "duration_s": 0.3, "timeout_s": 0.1}
    with fault_server(chunked) as server:
        report = run_load(LoadPlan(url=server.url, **plan))
    assert report["errors"] == 0 and report["ok"] > 0 and report["objects_per_response"] == 2.0
    with fault_server(failing) as server:
        report = run_load(LoadPlan(url=server.url, **plan))
    assert report["ok"] == 0 and set(report["errors_by_kind"]) == {HTTP_5XX}
    with fault_server(sleepy) as server:
        report = run_load(LoadPlan(url=server.url, **plan))
    assert report["ok"] == 0 and set(report["errors_by_kind"]) == {TIMEOUT}


def test_process_client_answers_like_the_thread_client_and_survives_its_child(udm):
    from twin.udm.process_client import UdmProcessClient

    url, store = udm
    client = UdmProcessClient(url, timeout_s=1.0)
    try:
        t_publish = time.monotonic()
        assert client.submit(*HAMBURG, side_m=200.0, frame=3, t_publish=t_publish)
        assert client.flush(5.0)
        (response,) = client.poll()
        assert response.ok and response.frame == 3 and response.t_publish == t_publish
        assert {o.id for o in response.objects} == {o.id for o in store.in_bbox(square_around(*HAMBURG, 200.0))}
        assert t_publish <= response.t_sent <= response.t_received  # one clock across both processes
        assert not client.submit(math.nan, 9.99, frame=4)
        assert [r.status for r in client.poll()] == [INVALID_FIX]
        client._child.process.kill()  # the child dies: the caller still never sees an exception
        client._child.process.wait(5)
        deadline = time.monotonic() + 5.0
        while client.submit(*HAMBURG, frame=5) and time.monotonic() < deadline:
            time.sleep(0.01)
        assert client.poll()[-1].status == "internal"
    finally:
        client.close()
    stats = client.stats()
    assert stats.ok == 1 and stats.errors.get(INVALID_FIX) == 1 and stats.errors.get("internal", 0) >= 1


def test_process_client_accounts_for_every_query_when_the_udm_is_unreachable():
    from twin.udm.process_client import UdmProcessClient

    with UdmProcessClient(f"http://127.0.0.1:{closed_port()}", max_retries=1, backoff_s=0.01,
                          queue_size=2) as client:
        for frame in range(20):
            assert client.submit(*HAMBURG, frame=frame)
        client.flush(5.0)
        responses = client.poll()
    stats = client.stats()
    assert responses and all(r.status == UNREACHABLE and r.attempts == 2 for r in responses)
    assert stats.submitted == 20 == len(responses) + stats.dropped + stats.abandoned


def test_one_connection_is_kept_alive_and_a_closed_one_is_reopened_without_an_error():
    """A raw HTTP server that counts connections and, on request, closes a connection after answering without
    saying so (as a server's keep-alive timeout does): the client reuses one connection while it stays open and
    notices the close before the next request, so no query fails or is retried because of it."""
    import json
    import threading

    body = json.dumps({"type": "FeatureCollection", "features": []}).encode()
    answer = (b"HTTP/1.1 200 OK\r\nContent-Type: application/geo+json\r\nContent-Length: "
              + str(len(body)).encode() + b"\r\n\r\n" + body)
    listener = socket.create_server(("127.0.0.1", 0))
    listener.settimeout(5.0)
    connections, close_after = [], set()

    def serve():
        while True:
            try:
                conn, _ = listener.accept()
            except OSError:
                return
            connections.append(conn)
            with conn:
                conn.settimeout(5.0)
                while True:
                    try:
                        request = conn.recv(65536)
                    except OSError:
                        break
                    if not request:
                        break
                    conn.sendall(answer)
                    if len(connections) in close_after:
                        break  # close without "Connection: close"

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    url = f"http://127.0.0.1:{listener.getsockname()[1]}"
    try:
        with UdmClient(url, max_retries=2) as client:
            for frame in range(4):
                client.submit(*HAMBURG, frame=frame)
                assert client.flush(5.0)
            assert len(connections) == 1  # kept alive
            close_after.add(1)
            client.submit(*HAMBURG, frame=4)
            assert client.flush(5.0)
            time.sleep(0.1)  # the server's close reaches the client while the connection is idle
            for frame in range(5, 8):
                client.submit(*HAMBURG, frame=frame)
                assert client.flush(5.0)
            responses = client.poll()
            stats = client.stats()
    finally:
        listener.close()
    assert [r.status for r in responses] == [OK] * 8 and all(r.attempts == 1 for r in responses)
    assert stats.retries == 0 and stats.errors == {} and len(connections) == 2


@pytest.mark.skipif(not hasattr(os, "sched_getscheduler"), reason="scheduling policies are Linux's")
def test_process_client_leaves_the_batch_policy_a_sweep_starts_drives_with(udm):
    """`twin sweep` starts drives under SCHED_BATCH; the UDM client's process must not keep it, or every answer
    would wait for the simulations of the other twins to finish their slices."""
    from twin.sweep.runs import batch_policy
    from twin.udm.process_client import UdmProcessClient

    url, _ = udm
    with batch_policy():
        client = UdmProcessClient(url, timeout_s=1.0)
        helper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        assert os.sched_getscheduler(helper.pid) == os.SCHED_BATCH  # what every child of the drive inherits
        assert os.sched_getscheduler(client._child.process.pid) == os.SCHED_OTHER
        assert client.submit(*HAMBURG, frame=1) and client.flush(5.0) and client.poll()[0].ok
    finally:
        helper.kill()
        helper.wait(5)
        client.close()
