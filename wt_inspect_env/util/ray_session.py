"""Ray start-up, shared by the evaluation harness and the seed trainer: join the cluster at an
address, or start a private local instance - never silently whatever else runs on the machine."""
from __future__ import annotations

import socket
from typing import Any

from . import ray_reaper


def import_ray() -> Any:
    """Import Ray, or raise an error that says which extra installs it."""
    try:
        import ray
    except ModuleNotFoundError:
        raise ValueError("backend 'ray' needs Ray, an optional dependency: pip install 'wt-inspect[ray]'") from None
    return ray


def check_ray_address(address: str, timeout_s: float = 5.0) -> None:
    """Refuse a ``host:port`` (or ``ray://host:port``) nothing answers on within ``timeout_s``:
    Ray itself keeps retrying such an address for many minutes without a word."""
    if address == "auto":
        return
    hostport = address.split("://", 1)[-1]
    host, sep, port = hostport.rpartition(":")
    if not sep or not port.isdigit():
        raise ValueError(f"address {address!r}: expected 'auto', 'host:port' or 'ray://host:port'")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s).close()
    except OSError as exc:
        raise ValueError(f"address {address!r}: nothing answers there ({exc}); start a cluster with "
                         "`ray start --head` or leave the address out for a local one") from None


def init_ray(address: str | None = None, num_cpus: int | None = None, *, log_to_driver: bool = True) -> bool:
    """Connect to the Ray cluster at ``address`` (``"auto"``, ``"host:6379"``, ``"ray://host:10001"``),
    or, without one, start a private local instance with ``num_cpus`` CPUs. Returns whether this
    call initialised Ray (the caller then shuts it down); an initialised session is used as it is.

    Without an address Ray itself would join whatever cluster ``RAY_ADDRESS`` or the last
    ``ray start`` on this machine points to - a stale or unrelated one - and then refuse
    ``num_cpus``; asking for ``"local"`` keeps a run without ``--address`` independent of what
    else runs on the machine."""
    ray = import_ray()
    if ray.is_initialized():
        return False
    kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": log_to_driver,
                              "configure_logging": False}
    if address:
        check_ray_address(address)
    try:
        if address:
            ray.init(address=address, **kwargs)
        else:
            # the processes this call starts are the private instance's: a reaper removes what is
            # left of them once this process is gone, however it ends (see ray_reaper)
            reaper = ray_reaper.Reaper()
            reaper.start()
            ray.init(address="local", num_cpus=num_cpus, **kwargs)
            reaper.started()
    except ConnectionError as exc:
        raise ValueError(f"address {address!r}: no Ray cluster to connect to there ({exc}); "
                         "start one with `ray start --head` or leave the address out for a local one") from None
    return True
