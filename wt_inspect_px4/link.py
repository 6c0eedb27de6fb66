"""MAVLink over UDP or TCP: pymavlink's generated common dialect on our own sockets, with a tlog.

Why own sockets and not ``mavutil.mavlink_connection``: the dialect is chosen there through a
process-wide environment variable (``MAVLINK20``) and a module global, while the bridge needs
MAVLink 2 (ODOMETRY is message 331) and two links in one process in the tests; the generated
``pymavlink.dialects.v20.common.MAVLink`` class packs and parses every message (no hand-written
framing) and is used here directly. Sending and parsing use separate instances (one per thread).

Endpoints, as MAVSDK writes them: ``udp://:14540`` listens on UDP port 14540 and answers the
address it hears from (PX4 SITL's offboard port); ``udp://HOST:PORT`` sends to HOST;
``tcp://:4560`` listens for one TCP client (PX4 SITL connects to its simulator there);
``tcp://HOST:PORT`` connects.

Every message in and out goes to the raw telemetry log when one is given: QGroundControl's and
MAVProxy's ``.tlog`` format (per message, a big-endian 64-bit Unix time in microseconds, then the
packet as sent on the wire), which ``mavlogdump.py`` and QGroundControl replay.

``LinkFaults`` drops and delays outgoing packets (a seeded random stream): the tests' lossy,
late link; off unless given.
"""
from __future__ import annotations

import heapq
import random
import socket
import struct
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable
from urllib.parse import urlsplit

from pymavlink.dialects.v20 import common as mavlink

# PX4's custom_mode: main mode in bits 16-23, sub mode in bits 24-31 (px4_custom_mode.h).
PX4_MAIN_MANUAL, PX4_MAIN_POSCTL, PX4_MAIN_AUTO, PX4_MAIN_OFFBOARD = 1, 3, 4, 6
PX4_AUTO_LOITER = 3


def px4_mode(main: int, sub: int = 0) -> int:
    """PX4's ``custom_mode`` word of a main / sub mode (as HEARTBEAT carries it)."""
    return (main << 16) | (sub << 24)


def px4_main_mode(custom_mode: int) -> int:
    """PX4's main flight mode from a heartbeat's ``custom_mode`` (its bits 16-23)."""
    return (int(custom_mode) >> 16) & 0xFF


OFFBOARD_MODE = px4_mode(PX4_MAIN_OFFBOARD)
HOLD_MODE = px4_mode(PX4_MAIN_AUTO, PX4_AUTO_LOITER)     # AUTO.LOITER: PX4's "Hold"


@dataclass(frozen=True)
class Endpoint:
    """A parsed endpoint URL (see the module docstring)."""

    kind: str         # "udp" or "tcp"
    host: str         # "" = listen
    port: int

    @classmethod
    def parse(cls, url: str, option: str = "endpoint") -> "Endpoint":
        """The endpoint of a URL such as ``udp://:14540`` or ``tcp://HOST:PORT`` (``option`` names it in errors)."""
        if not isinstance(url, str) or "://" not in url:
            raise ValueError(f"{option} must look like udp://:14540, udp://HOST:PORT, tcp://:4560 or "
                             f"tcp://HOST:PORT, got {url!r}")
        parts = urlsplit(url)
        if parts.scheme not in ("udp", "tcp"):
            raise ValueError(f"{option} scheme must be udp or tcp, got {parts.scheme!r} in {url!r}")
        try:
            port = parts.port
        except ValueError:
            port = None
        if port is None or not 0 < port < 65536 or parts.path not in ("", "/"):
            raise ValueError(f"{option} needs a port in 1..65535 (e.g. {parts.scheme}://:14540), got {url!r}")
        return cls(parts.scheme, parts.hostname or "", port)

    @property
    def listens(self) -> bool:
        """Whether this end waits for the peer (no host given) rather than contacting it."""
        return self.host == ""


@dataclass(frozen=True)
class LinkFaults:
    """Packet loss and latency applied to *outgoing* packets (for tests): each packet is dropped
    with probability ``loss`` and otherwise delivered after a delay uniform in ``latency_s``."""

    loss: float = 0.0
    latency_s: tuple[float, float] = (0.0, 0.0)
    seed: int = 0


class _Transport:
    """A datagram or stream socket behind ``send(bytes)`` / ``recv() -> bytes``."""

    def __init__(self, ep: Endpoint, accept_timeout: float) -> None:
        self.ep = ep
        self.peer: tuple[str, int] | None = None
        self._accept_timeout = accept_timeout
        self.conn: socket.socket | None = None
        if ep.kind == "udp":
            self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            if ep.listens:
                self.sock.bind(("0.0.0.0", ep.port))
            else:
                self.sock.bind(("0.0.0.0", 0))
                self.peer = (socket.gethostbyname(ep.host), ep.port)
            self.sock.settimeout(0.05)
        elif ep.listens:
            self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self.sock.bind(("0.0.0.0", ep.port))
            self.sock.listen(1)
            self.sock.settimeout(0.05)
        else:
            self.sock = socket.create_connection((ep.host, ep.port), timeout=accept_timeout)
            self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self.sock.settimeout(0.05)
            self.conn = self.sock

    @property
    def local_port(self) -> int:
        return int(self.sock.getsockname()[1])

    def send(self, data: bytes) -> None:
        try:
            if self.ep.kind == "udp":
                if self.peer is not None:
                    self.sock.sendto(data, self.peer)
            elif self.conn is not None:
                self.conn.sendall(data)
        except OSError:
            pass   # a vanished peer is the link-loss path, detected by silence on the reading side

    def recv(self) -> bytes:
        """Bytes received (b"" after a 50 ms timeout)."""
        try:
            if self.ep.kind == "udp":
                data, addr = self.sock.recvfrom(65535)
                if self.ep.listens:
                    self.peer = addr
                return data
            if self.conn is None:
                conn, addr = self.sock.accept()
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                conn.settimeout(0.05)
                self.conn, self.peer = conn, addr
                return b""
            data = self.conn.recv(65535)
            if not data:             # the peer closed the stream
                self.conn.close()
                self.conn = None
            return data
        except (socket.timeout, BlockingIOError):
            return b""
        except OSError:
            return b""

    def close(self) -> None:
        for s in {self.conn, self.sock} - {None}:
            try:
                s.close()
            except OSError:
                pass


class _Tlog:
    """Append-only .tlog writer (thread-safe)."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._f = open(self.path, "wb")
        self._lock = threading.Lock()

    def write(self, packet: bytes) -> None:
        with self._lock:
            if not self._f.closed:
                self._f.write(struct.pack(">Q", int(time.time() * 1e6)) + packet)

    def close(self) -> None:
        with self._lock:
            self._f.close()


class _Writer:
    """The ``file`` pymavlink's encoder writes packed messages to."""

    def __init__(self, link: "MavlinkLink") -> None:
        self.link = link

    def write(self, buf: bytes) -> None:
        self.link._out(bytes(buf))


MessageHandler = Callable[[Any], None]


class MavlinkLink:
    """One MAVLink 2 connection: a reader thread parses what arrives and calls ``handler(msg)``
    for every message; :meth:`send` packs and sends. ``tlog``: path of the raw log (optional)."""

    def __init__(self, endpoint: str | Endpoint, *, system_id: int = 255, component_id: int = 190,
                 handler: MessageHandler | None = None, tlog: str | Path | None = None,
                 faults: LinkFaults | None = None, accept_timeout: float = 10.0) -> None:
        self.endpoint = endpoint if isinstance(endpoint, Endpoint) else Endpoint.parse(endpoint)
        self.handler = handler
        self._tlog = _Tlog(Path(tlog)) if tlog is not None else None
        try:
            self._transport = _Transport(self.endpoint, accept_timeout)
        except OSError as exc:
            if self._tlog is not None:
                self._tlog.close()
            raise ValueError(f"cannot open {self.endpoint.kind}://{self.endpoint.host}:{self.endpoint.port}: "
                             f"{exc.strerror or exc}") from None
        self._send_lock = threading.Lock()
        self._encoder = mavlink.MAVLink(_Writer(self), srcSystem=system_id, srcComponent=component_id)
        self._parser = mavlink.MAVLink(None)
        self._parser.robust_parsing = True
        self.faults = faults
        self._rng = random.Random(faults.seed if faults else 0)
        self._delayed: list[tuple[float, int, bytes]] = []
        self._delay_cv = threading.Condition()
        self._seq = 0
        self.last_rx = 0.0            # monotonic time of the last message received
        self.rx_count = 0
        self.tx_count = 0
        self._stop = threading.Event()
        self._reader = threading.Thread(target=self._read_loop, name="mavlink-reader", daemon=True)
        self._reader.start()
        self._delayer: threading.Thread | None = None
        if faults is not None and faults.latency_s[1] > 0:
            self._delayer = threading.Thread(target=self._delay_loop, name="mavlink-delay", daemon=True)
            self._delayer.start()

    # ------------------------------------------------------------------ sending
    @property
    def mav(self) -> Any:
        """The encoder (``link.mav.heartbeat_encode(...)`` builds a message for :meth:`send`)."""
        return self._encoder

    @property
    def local_port(self) -> int:
        """The local port the transport is bound to (useful when it was 0: any free port)."""
        return self._transport.local_port

    @property
    def connected(self) -> bool:
        """A peer is known (UDP: heard from or given; TCP: accepted or connected)."""
        t = self._transport
        return t.peer is not None and (t.ep.kind == "udp" or t.conn is not None)

    def send(self, msg: Any) -> None:
        """Encode and send one MAVLink message (thread-safe)."""
        with self._send_lock:
            self._encoder.send(msg)

    def _out(self, packet: bytes) -> None:
        self.tx_count += 1
        if self._tlog is not None:
            self._tlog.write(packet)
        f = self.faults
        if f is None:
            self._transport.send(packet)
            return
        if f.loss > 0 and self._rng.random() < f.loss:
            return
        lo, hi = f.latency_s
        if hi <= 0:
            self._transport.send(packet)
            return
        due = time.monotonic() + self._rng.uniform(lo, hi)
        with self._delay_cv:
            self._seq += 1
            heapq.heappush(self._delayed, (due, self._seq, packet))
            self._delay_cv.notify()

    def _delay_loop(self) -> None:
        while not self._stop.is_set():
            with self._delay_cv:
                if not self._delayed:
                    self._delay_cv.wait(0.05)
                    continue
                due, _, packet = self._delayed[0]
                wait = due - time.monotonic()
                if wait > 0:
                    self._delay_cv.wait(min(wait, 0.05))
                    continue
                heapq.heappop(self._delayed)
            self._transport.send(packet)

    # ------------------------------------------------------------------ receiving
    def _read_loop(self) -> None:
        while not self._stop.is_set():
            data = self._transport.recv()
            if not data:
                continue
            try:
                msgs = self._parser.parse_buffer(data) or []
            except mavlink.MAVError:
                continue
            for msg in msgs:
                if msg.get_type() == "BAD_DATA":
                    continue
                self.last_rx = time.monotonic()
                self.rx_count += 1
                if self._tlog is not None:
                    self._tlog.write(bytes(msg.get_msgbuf()))
                if self.handler is not None:
                    try:
                        self.handler(msg)
                    except Exception:   # pragma: no cover - a handler bug must not kill the link
                        import traceback
                        traceback.print_exc()

    def close(self) -> None:
        """Stop the reader (and the delay thread, if any) and close the transport."""
        self._stop.set()
        self._reader.join(timeout=1.0)
        if self._delayer is not None:
            self._delayer.join(timeout=1.0)
        self._transport.close()
        if self._tlog is not None:
            self._tlog.close()

    def __enter__(self) -> "MavlinkLink":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def read_tlog(path: str | Path) -> list[tuple[float, Any]]:
    """The messages of a tlog as (unix time [s], message), parsed with the same dialect."""
    data = Path(path).read_bytes()
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    out: list[tuple[float, Any]] = []
    i = 0
    while i + 8 <= len(data):
        (t_us,) = struct.unpack(">Q", data[i:i + 8])
        i += 8
        # a MAVLink 2 packet: 0xFD, payload length, ... ; length = 12 + payload (+13 if signed)
        if data[i] == 0xFD:
            n = 12 + data[i + 1] + (13 if data[i + 2] & 0x01 else 0)
        else:                 # MAVLink 1: 0xFE, length, ... ; 8 + payload
            n = 8 + data[i + 1]
        msgs = parser.parse_buffer(data[i:i + n]) or []
        out += [(t_us / 1e6, m) for m in msgs if m.get_type() != "BAD_DATA"]
        i += n
    return out
