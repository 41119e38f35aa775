"""A local cluster (`--cluster local:N`) runs in a network namespace of its own whose only interface
is loopback: Ray 2.60's servers listen on every interface they see, and there they see only that.
While a render runs on it, none of its processes listens in this (the machine's) namespace."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from thurston_addon.farm import cluster

pytestmark = pytest.mark.slow
THURSTON = Path(sys.executable).with_name("thurston")


def descendants(root: int) -> dict[int, str]:
    """The processes below `root`: pid -> command name."""
    parent, name = {}, {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            text = stat.read_text()
        except OSError:
            continue
        pid, rest = text.split(" (", 1)
        comm, fields = rest.rsplit(") ", 1)
        parent[int(pid)], name[int(pid)] = int(fields.split()[1]), comm
    found, frontier = {}, [root]
    while frontier:
        p = frontier.pop()
        for child, up in parent.items():
            if up == p and child not in found:
                found[child] = name[child]
                frontier.append(child)
    return found


def listening_pids() -> set[int]:
    out = subprocess.run(["ss", "-ltnpH"], capture_output=True, text=True).stdout
    return {int(p) for p in re.findall(r"pid=(\d+)", out)}


def test_a_local_cluster_listens_only_in_its_own_network(tmp_path):
    if shutil.which("ss") is None:
        pytest.skip("needs ss (iproute2) to list the machine's listening sockets")
    if cluster.private_network_command(["true"]) is None:
        pytest.skip("this system allows no network namespace (the cluster then warns that its ports are open)")
    probe = [sys.executable, "-c", "import socket; print([n for _, n in socket.if_nameindex()])"]
    inside = subprocess.run(cluster.private_network_command(probe), capture_output=True, text=True, timeout=60)
    assert inside.stdout.strip() == "['lo']", inside.stderr
    out = tmp_path / "torus.png"
    render = subprocess.Popen(
        [str(THURSTON), "render", "--space", "torus", "--size", "32x18", "--quality", "draft", "--shading", "normal"]
        + ["--cluster", "local:1", "--tiles", "2", "--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    ray_seen, listening_here = set(), set()
    while render.poll() is None:
        below = descendants(render.pid)
        ray_seen |= {pid for pid, comm in below.items() if comm in ("gcs_server", "raylet")}
        listening_here |= listening_pids() & set(below)
        time.sleep(0.2)
    stdout, stderr = render.communicate()
    assert render.returncode == 0 and out.is_file(), stderr
    assert ray_seen, "the render's Ray processes were not seen"
    assert not listening_here, f"processes of the local cluster listen in the machine's network: {listening_here}"
    assert "listen on this machine's network interfaces" not in stderr
