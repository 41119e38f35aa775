"""The cluster a farm runs on: `local[:N]`, Ray started in this process with N worker slots, its node
on the loopback address, no dashboard, token authentication on, and (where Linux allows a network
namespace: private_network_command) in a network namespace of its own whose only interface is
loopback, since Ray 2.60's servers listen on every interface they see (docs/farm.md, "Security");
`HOST:PORT`, a running cluster joined. Ray is imported here, when a farm runs, never by the plain
render path."""

from __future__ import annotations

import contextlib
import fcntl
import os
import re
import shutil
import socket
import struct
import subprocess
import warnings

RAY_MISSING = "--cluster needs Ray: install the 'farm' extra (pip install 'thurston[farm]', or pip install ray==2.60.0)"
LOOPBACK = "127.0.0.1"
CONNECT_SECONDS = 10
# set in a process that runs in a network namespace of its own (private_network_command)
PRIVATE_NETWORK = "THURSTON_PRIVATE_NETWORK"
# util-linux's unshare: a user namespace mapping this user to root in it, which owns a new network
# namespace; no privilege needed where the system allows user namespaces
UNSHARE = ["unshare", "--user", "--map-root-user", "--net"]
NOT_PRIVATE = (
    "the local cluster's ports listen on this machine's network interfaces (Ray binds every interface; its "
    "token authentication guards them): this system allows no network namespace of our own to hide them in; "
    "keep a firewall closed to them (docs/farm.md, Security)"
)


class FarmError(Exception):
    """A farm that cannot run, with a message naming the problem and what to change."""


def import_ray():
    try:
        import ray
    except ImportError:
        raise FarmError(RAY_MISSING) from None
    return ray


def parse_address(address: str) -> tuple[str, int | None]:
    """('local', N or None: this machine's cores) or ('HOST:PORT', None)."""
    m = re.fullmatch(r"local(?::(\d+))?", address)
    if m:
        n = int(m.group(1)) if m.group(1) else None
        if n is not None and n < 1:
            raise FarmError(f"--cluster {address!r}: local:N needs at least one worker")
        return "local", n
    m = re.fullmatch(r"([A-Za-z0-9.\-]+|\[[0-9A-Fa-f:]+\]):(\d{1,5})", address)
    if not m or not 0 < int(m.group(2)) < 65536:
        raise FarmError(f"--cluster {address!r}: expected local, local:N (workers on this machine) or HOST:PORT")
    return address, None


@contextlib.contextmanager
def connected(address: str):
    """Ray connected to the cluster of `address` for the block (a local one started and stopped
    with it)."""
    ray = import_ray()
    where, workers = parse_address(address)
    quiet = dict(logging_level="ERROR", log_to_driver=False, configure_logging=True)
    try:
        if where == "local":
            if os.environ.get(PRIVATE_NETWORK):
                _loopback_up()
            else:
                warnings.warn(NOT_PRIVATE)
            ray.init(
                num_cpus=workers or os.cpu_count() or 1,
                include_dashboard=False,
                _node_ip_address=LOOPBACK,  # its processes reach each other over loopback
                **quiet,
            )
        else:
            _check_reachable(where)
            ray.init(address=where, **quiet)
    except (ConnectionError, RuntimeError, ValueError) as exc:
        raise FarmError(f"--cluster {address}: cannot connect: {str(exc).strip().splitlines()[0]}") from None
    try:
        yield
    finally:
        ray.shutdown()


def is_local(address: str | None) -> bool:
    return bool(address) and re.fullmatch(r"local(:\d+)?", address) is not None


def private_network_command(argv: list[str]) -> list[str] | None:
    """argv run in a network namespace of its own (its only interface loopback, which nothing
    outside reaches), or None where this process is already in one or the system allows none."""
    if os.environ.get(PRIVATE_NETWORK) or shutil.which("unshare") is None:
        return None
    if subprocess.run([*UNSHARE, "true"], capture_output=True).returncode != 0:
        return None
    return [*UNSHARE, *argv]


def _loopback_up():
    """A new network namespace's loopback interface is down: up, so the cluster's processes reach
    each other (SIOCSIFFLAGS: IFF_UP | IFF_LOOPBACK | IFF_RUNNING)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        fcntl.ioctl(s.fileno(), 0x8914, struct.pack("16sH14s", b"lo", 0x1 | 0x8 | 0x40, b""))


def _check_reachable(address: str):
    """Ray waits minutes for a head that is not there: a plain connection to it first."""
    host, _, port = address.rpartition(":")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=CONNECT_SECONDS).close()
    except OSError as exc:
        raise FarmError(
            f"--cluster {address}: no Ray cluster answers there ({exc.strerror or exc}); start one with "
            f"`ray start --head --port={port}` on that machine, or check the address"
        ) from None


def cpus_busy() -> int:
    """The CPUs of the cluster that tasks hold now."""
    ray = import_ray()
    total, free = ray.cluster_resources().get("CPU", 0), ray.available_resources().get("CPU", 0)
    return int(round(total - free))
