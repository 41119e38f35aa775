"""The cluster a farm runs on: `local[:N]`, Ray started in this process with N worker slots, its node
on the loopback address, no dashboard, token authentication on (Ray 2.60's servers still listen on
every interface: docs/farm.md, "Security"); `HOST:PORT`, a running cluster joined. Ray is imported
here, when a farm runs, never by the plain render path."""

from __future__ import annotations

import contextlib
import os
import re
import socket

RAY_MISSING = "--cluster needs Ray: install the 'farm' extra (pip install 'thurston[farm]', or pip install ray==2.60.0)"
LOOPBACK = "127.0.0.1"
CONNECT_SECONDS = 10


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
