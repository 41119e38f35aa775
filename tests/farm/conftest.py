"""A real Ray cluster on loopback for the farm tests: a head and a second node, separate processes
(`ray start --block`, each in its own process group), one CPU each, their files under a temporary
folder; started once per test session (a Ray driver keeps the first cluster's token) and always
torn down, every process they started killed."""

import contextlib
import os
import secrets
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

RAY = Path(sys.executable).with_name("ray")
START_SECONDS = 120


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _started_by(folder: str) -> list[int]:
    """The processes whose command line names the cluster's folder, or whose parent's does (the
    workers, renamed ray::...)."""

    def cmdline(pid):
        try:
            return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            return ""

    def parent(pid):
        try:
            return int(Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()[1])
        except (OSError, ValueError, IndexError):
            return 0

    pids = [int(p) for p in os.listdir("/proc") if p.isdigit()]
    ours = {p for p in pids if folder in cmdline(p)}
    for _ in range(3):  # children of ours (workers) and theirs
        ours |= {p for p in pids if parent(p) in ours}
    ours.discard(os.getpid())
    return sorted(ours)


@pytest.fixture(scope="session")
def cluster(tmp_path_factory):
    """The head's address (127.0.0.1:PORT) of a two-node cluster; its processes are killed after
    the tests and checked gone."""
    folder = str(tmp_path_factory.mktemp("ray"))
    port = _free_port()
    common = ["--block", "--num-cpus=1", "--node-ip-address=127.0.0.1", "--disable-usage-stats"]
    common += ["--object-store-memory=100000000", f"--temp-dir={folder}"]
    # Ray 2.60's servers listen on every interface whatever the node's address: what keeps others
    # out is its token authentication, here with a token of this cluster's own (not ~/.ray's)
    token = {"RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": secrets.token_hex(16)}
    saved = {k: os.environ.get(k) for k in token}
    os.environ.update(token)  # the tests' driver (this process) too
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0"}
    nodes = []

    def start(args):
        log = open(Path(folder) / f"node{len(nodes)}.log", "wb")
        nodes.append(
            subprocess.Popen(
                [str(RAY), "start", *args, *common], stdout=log, stderr=log, env=env, start_new_session=True
            )
        )

    try:
        start(["--head", f"--port={port}", "--include-dashboard=false"])
        address = f"127.0.0.1:{port}"
        _wait_for(lambda: _answers(port), "the head")
        start([f"--address={address}"])
        import ray

        ray.init(address=address, logging_level="ERROR", log_to_driver=False)
        try:
            _wait_for(lambda: sum(n["Alive"] for n in ray.nodes()) == 2, "the second node")
        finally:
            ray.shutdown()
        yield {"address": address, "folder": folder, "processes": lambda: _started_by(folder)}
    finally:
        for node in nodes:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(node.pid, signal.SIGTERM)
        deadline = time.monotonic() + 3  # Ray drains for up to 30 s: then killed
        while _started_by(folder) and time.monotonic() < deadline:
            time.sleep(0.2)
        for pid in _started_by(folder):
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        for node in nodes:
            node.wait(timeout=10)
        for k, v in saved.items():
            os.environ.pop(k) if v is None else os.environ.__setitem__(k, v)
        assert not _started_by(folder), "Ray processes of the test cluster survived it"


def _answers(port) -> bool:
    try:
        socket.create_connection(("127.0.0.1", port), timeout=1).close()
        return True
    except OSError:
        return False


def _wait_for(condition, what):
    deadline = time.monotonic() + START_SECONDS
    while not condition():
        if time.monotonic() > deadline:
            raise TimeoutError(f"the test's Ray cluster: {what} did not start in {START_SECONDS} s")
        time.sleep(0.5)
