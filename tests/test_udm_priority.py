"""The UDM path at real-time priority: ``realtime_policy`` in real child processes, permitted and not, and a real
``twin drive --udm-realtime`` against a real ``twin udm serve --realtime`` on loopback."""

from __future__ import annotations

import json
import os
import re
import resource
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

from twin.sweep.plan import DriveOptions
from twin.udm.priority import REALTIME_PRIORITY

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="scheduling policies are Linux's")

# What a child reports: realtime_policy's answer, then its own policy and priority and those of a thread it
# starts afterwards (threads inherit the policy: the server's later threads run under it too).
PROBE = """
import json, os, threading
from twin.udm.priority import realtime_policy
reason = realtime_policy("the probe")
seen = []
thread = threading.Thread(target=lambda: seen.append(os.sched_getscheduler(0)))
thread.start(); thread.join()
print(json.dumps({"reason": reason, "policy": os.sched_getscheduler(0), "priority": os.sched_getparam(0).sched_priority,
                  "thread_policy": seen[0]}))
"""


def may_use_fifo() -> bool:
    """Whether this process may ask for SCHED_FIFO: CAP_SYS_NICE in its effective set (root in a container often
    lacks it) or an rtprio limit high enough."""
    status = Path("/proc/self/status").read_text()
    effective = int(re.search(r"^CapEff:\s*([0-9a-f]+)", status, re.MULTILINE).group(1), 16)
    return bool(effective >> 23 & 1) or resource.getrlimit(resource.RLIMIT_RTPRIO)[0] >= REALTIME_PRIORITY


# Runs a command without the right to SCHED_FIFO, as for an ordinary user: no rtprio limit and, for root, no
# CAP_SYS_NICE after the exec (dropped from the bounding set; the inheritable set is empty). A trampoline
# process, not a preexec_fn: the test process has threads.
WITHOUT_FIFO = """
import ctypes, os, resource, sys
resource.setrlimit(resource.RLIMIT_RTPRIO, (0, 0))
if os.geteuid() == 0 and ctypes.CDLL(None, use_errno=True).prctl(24, 23, 0, 0, 0) != 0:  # PR_CAPBSET_DROP, CAP_SYS_NICE
    sys.exit(f"prctl(PR_CAPBSET_DROP, CAP_SYS_NICE): {os.strerror(ctypes.get_errno())}")
os.execv(sys.argv[1], sys.argv[1:])
"""


def without_fifo(command: list[str]) -> list[str]:
    return [sys.executable, "-c", WITHOUT_FIFO, *command]


def probe(permitted: bool = True) -> dict:
    command = [sys.executable, "-c", PROBE]
    result = subprocess.run(command if permitted else without_fifo(command), capture_output=True, text=True,
                            timeout=60, check=True)
    return json.loads(result.stdout)


@pytest.mark.skipif(not may_use_fifo(), reason="needs root, CAP_SYS_NICE or an rtprio limit >= 10")
def test_realtime_policy_puts_the_calling_thread_under_fifo():
    facts = probe()
    assert facts["reason"] is None
    assert facts["policy"] == os.SCHED_FIFO and facts["priority"] == REALTIME_PRIORITY
    assert facts["thread_policy"] == os.SCHED_FIFO
    assert os.sched_getscheduler(0) != os.SCHED_FIFO  # the caller of the child is untouched


def test_realtime_policy_not_permitted_says_why_in_one_line_and_keeps_the_policy():
    try:
        facts = probe(permitted=False)
    except subprocess.CalledProcessError as error:
        pytest.skip(f"cannot make a child without the right to SCHED_FIFO here: {error.stderr.strip()[-200:]}")
    reason = facts["reason"]
    assert reason is not None and "\n" not in reason
    assert "the probe stays at normal priority" in reason and "not permitted" in reason
    assert "CAP_SYS_NICE" in reason and "root" in reason and "ulimit -r 10" in reason
    assert facts["policy"] == os.SCHED_OTHER and facts["thread_policy"] == os.SCHED_OTHER


def test_a_sweep_hands_udm_realtime_to_every_drive():
    options = DriveOptions(udm="http://127.0.0.1:8765", udm_realtime=True)
    arguments = options.arguments(3)
    assert arguments[arguments.index("--udm") + 1] == "http://127.0.0.1:8765" and "--udm-realtime" in arguments
    assert "--udm-realtime" not in DriveOptions(udm="http://127.0.0.1:8765").arguments(3)


def start_serve(build, *options: str, permitted: bool = True) -> tuple[subprocess.Popen, str]:
    command = [sys.executable, "-m", "twin.cli.main", "udm", "serve", "--port", "0", "--map", str(build),
               "--token", "t", *options]
    process = subprocess.Popen(command if permitted else without_fifo(command), stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
    first = process.stdout.readline()
    match = re.search(r"http://127\.0\.0\.1:\d+", first)
    if match is None:
        process.kill()
        raise AssertionError(f"twin udm serve did not start: {first!r} {process.stderr.read()}")
    url = match.group(0)
    deadline = time.monotonic() + 20.0
    while True:  # the URL is printed just before uvicorn starts accepting
        try:
            httpx.get(f"{url}/health", trust_env=False, timeout=1.0).raise_for_status()
            return process, url
        except httpx.HTTPError:
            assert time.monotonic() < deadline, "twin udm serve did not answer /health"
            time.sleep(0.05)


def drive(build, out, url, permitted: bool = True) -> tuple[dict, str]:
    command = [sys.executable, "-m", "twin.cli.main", "drive", "--map", str(build), "--random", "--duration", "8",
               "--seed", "4", "--pace", "2", "--no-plot", "--no-record", "-o", str(out), "--json", "--udm", url,
               "--udm-every", "5", "--udm-realtime"]
    result = subprocess.run(command if permitted else without_fifo(command), capture_output=True, text=True,
                            timeout=300, check=False)
    assert result.returncode == 0, result.stderr[-2000:]
    return json.loads(result.stdout[result.stdout.index("{"):]), result.stderr


@pytest.mark.skipif(not may_use_fifo(), reason="needs root, CAP_SYS_NICE or an rtprio limit >= 10")
def test_a_realtime_drive_against_a_realtime_server_gets_its_answers(sample_build_dir, tmp_path):
    server, url = start_serve(sample_build_dir, "--realtime")
    try:
        assert os.sched_getscheduler(server.pid) == os.SCHED_FIFO  # the thread that runs uvicorn's loop
        assert os.sched_getparam(server.pid).sched_priority == REALTIME_PRIORITY
        metrics, stderr = drive(sample_build_dir, tmp_path / "drive", url)
    finally:
        server.terminate()
        server.wait(10)
    udm = metrics["udm"]
    # the client process's policy as the OS reported it while the drive ran (os.sched_getscheduler of its pid)
    assert udm["client"]["realtime"] is True and udm["client"]["policy"] == "fifo"
    assert udm["queries"] >= 30 and udm["error_count"] == 0 and udm["client"]["ok"] == udm["client"]["submitted"]
    assert udm["latency_ms"]["request"]["n"] >= 25
    assert "normal priority" not in stderr


def test_where_fifo_is_not_permitted_both_ends_warn_once_and_serve_at_normal_priority(sample_build_dir, tmp_path):
    server, url = start_serve(sample_build_dir, "--realtime", permitted=False)
    try:
        assert os.sched_getscheduler(server.pid) == os.SCHED_OTHER
        metrics, stderr = drive(sample_build_dir, tmp_path / "drive", url, permitted=False)
    finally:
        server.terminate()
        server.wait(10)
        server_log = server.stderr.read()
    assert server_log.count("the UDM server stays at normal priority") == 1 and "not permitted" in server_log
    assert stderr.count("warning: the UDM client process stays at normal priority: SCHED_FIFO is not permitted") == 1
    udm = metrics["udm"]
    assert udm["client"]["realtime"] is True and udm["client"]["policy"] == "other"
    assert udm["error_count"] == 0 and udm["latency_ms"]["request"]["n"] >= 25
