"""Checks of a ``--scheduler`` address before any work is sent to it.

Three checks, each ending in one :class:`~cellplan.errors.ArgumentError` line on
``--scheduler`` (exit status 2):

1. :func:`check_scheduler_address`: the form. Only ``tcp://HOST:PORT``:
   ``tls://`` and ``wss://`` need certificates cellplan has no options for, ``ucx://``
   needs UCX packages, ``ws://`` needs a scheduler started for it, so they are
   refused up front rather than failing inside Dask.
2. :func:`probe_scheduler`: a raw socket, with one overall deadline
   (:data:`PROBE_TIMEOUT_S`, name lookup included), reads what the server says on
   connection. A Dask scheduler speaks first: its handshake, one message in Dask's
   TCP framing (an 8-byte length, a frame count, the frame lengths, then msgpack).
   At most :data:`MAX_HANDSHAKE_BYTES` are read and the framing must add up and decode
   to a mapping, so an HTTP server, a stream of junk, a server that closes at once or
   one that never answers is refused without Dask ever reading it. (Dask would take
   the first 8 bytes of ``HTTP/1.1`` as a message length of 3 EiB and try to
   allocate it, and it waits for a handshake without a time limit.)
3. :func:`connect_client`: Dask's own connection and the first call to the
   scheduler, under one deadline (:data:`CLIENT_TIMEOUT_S`), for a server that passes
   the probe and then stops answering.

What the probe cannot do: tell a real scheduler from a server that imitates its
handshake; such a server is cut off by the deadline of step 3 instead.
"""

from __future__ import annotations

import re
import socket
import struct
import threading
import time
from collections.abc import Callable
from typing import Any, TypeVar

from cellplan.errors import ArgumentError

PROBE_TIMEOUT_S = 5.0
"""Seconds to connect to the scheduler and read its handshake, name lookup included."""

CLIENT_TIMEOUT_S = 10.0
"""Seconds for Dask's client to connect and get the scheduler's first answer."""

MAX_HANDSHAKE_BYTES = 64 * 1024
"""The most the probe reads; a Dask handshake is under 100 bytes."""

_ADDRESS_RE = re.compile(r"^tcp://(\[[0-9a-fA-F:.]+\]|[A-Za-z0-9_.-]+):(\d+)$")
_OTHER_PROTOCOLS = ("tls", "ws", "wss", "ucx", "inproc")

T = TypeVar("T")


def check_scheduler_address(address: str) -> str:
    """Validate a Dask scheduler address such as ``tcp://10.0.0.5:8786``; return it unchanged."""
    scheme = address.split("://", 1)[0].lower() if "://" in address else ""
    if scheme in _OTHER_PROTOCOLS:
        raise ArgumentError(
            f"{scheme}:// addresses are not supported (they need settings cellplan does not "
            f"pass to Dask); give the scheduler's tcp://HOST:PORT address",
            "--scheduler",
        )
    match = _ADDRESS_RE.match(address)
    if not match or not 0 < int(match.group(2)) < 65536:
        raise ArgumentError(
            f"expected an address like tcp://HOST:8786, got {address!r}", "--scheduler"
        )
    return address


def _host_port(address: str) -> tuple[str, int]:
    match = _ADDRESS_RE.match(check_scheduler_address(address))
    assert match is not None
    return match.group(1).strip("[]"), int(match.group(2))


def _refuse(address: str, why: str) -> ArgumentError:
    return ArgumentError(f"{address}: not a Dask scheduler ({why})", "--scheduler")


def probe_scheduler(address: str, timeout: float | None = None) -> None:
    """Refuse ``address`` unless a Dask scheduler's handshake comes back in time.

    Raises :class:`~cellplan.errors.ArgumentError` on ``--scheduler``: unreachable
    (``cannot reach``), or reachable but not answering like Dask (``not a Dask
    scheduler``). See the module docstring.
    """
    limit = PROBE_TIMEOUT_S if timeout is None else timeout
    host, port = _host_port(address)
    try:
        run_with_deadline(lambda: _probe(address, host, port, limit), limit + 1.0)
    except TimeoutError:
        raise _refuse(address, f"no answer within {limit:g} s") from None


def _probe(address: str, host: str, port: int, limit: float) -> None:
    deadline = time.monotonic() + limit
    try:
        sock = socket.create_connection((host, port), timeout=limit)
    except OSError as exc:
        raise ArgumentError(
            f"cannot reach the Dask scheduler {address}: {exc.strerror or exc}", "--scheduler"
        ) from None
    with sock:
        head = _read(sock, 8, deadline, address)
        (size,) = struct.unpack("Q", head)
        if not 16 <= size <= MAX_HANDSHAKE_BYTES:
            raise _refuse(address, f"its first bytes {_show(head)} are not a Dask message")
        body = _read(sock, size, deadline, address)
    (count,) = struct.unpack_from("Q", body)
    if not 1 <= count <= 16 or 8 + 8 * count > size:
        raise _refuse(address, f"its first bytes {_show(head + body)} are not a Dask message")
    lengths = struct.unpack_from(f"{count}Q", body, 8)
    if 8 + 8 * count + sum(lengths) != size:
        raise _refuse(address, "its first message's frame lengths do not add up")
    import msgpack

    start = 8 + 8 * count
    try:
        hello = msgpack.unpackb(body[start : start + lengths[0]], raw=False)
    except Exception:  # msgpack raises several types for bad input
        hello = None
    if not isinstance(hello, dict):
        raise _refuse(address, "its handshake is not a msgpack mapping")


def _read(sock: socket.socket, n: int, deadline: float, address: str) -> bytes:
    data = bytearray()
    while len(data) < n:
        left = deadline - time.monotonic()
        if left <= 0:
            raise _refuse(address, "no handshake within the time limit")
        sock.settimeout(left)
        try:
            chunk = sock.recv(n - len(data))
        except TimeoutError:
            raise _refuse(address, "it accepted the connection but sent nothing") from None
        except OSError as exc:
            raise _refuse(address, f"the connection failed: {exc.strerror or exc}") from None
        if not chunk:
            what = "closed the connection without a word" if not data else "stopped mid-message"
            raise _refuse(address, f"it {what}")
        data += chunk
    return bytes(data)


def _show(data: bytes) -> str:
    return repr(data[:16])


def connect_client(address: str, timeout: float | None = None) -> Any:
    """A :class:`distributed.Client` on ``address``, after :func:`probe_scheduler`.

    The connection and the first ``scheduler_info`` call run under one deadline
    (:data:`CLIENT_TIMEOUT_S`); past it, or on a failure, one
    :class:`~cellplan.errors.ArgumentError` line on ``--scheduler``.
    """
    from distributed import Client

    limit = CLIENT_TIMEOUT_S if timeout is None else timeout
    probe_scheduler(address)

    def start() -> Any:
        client = Client(address, timeout=f"{limit}s")
        try:
            client.scheduler_info()
        except BaseException:
            client.close()
            raise
        return client

    try:
        return run_with_deadline(start, limit)
    except TimeoutError:
        raise _refuse(address, f"no answer to the client within {limit:g} s") from None
    except ArgumentError:
        raise
    except Exception as exc:
        raise ArgumentError(
            f"cannot use the Dask scheduler {address}: {type(exc).__name__}: {exc}"[:300],
            "--scheduler",
        ) from None


def run_with_deadline(fn: Callable[[], T], seconds: float) -> T:
    """``fn()`` in a daemon thread; its result or exception, or :class:`TimeoutError`.

    Past the deadline the thread is abandoned (it cannot be stopped from outside);
    being a daemon, it does not keep the interpreter from exiting.
    """
    box: dict[str, Any] = {}

    def target() -> None:
        try:
            box["value"] = fn()
        except BaseException as exc:  # handed to the caller
            box["error"] = exc

    thread = threading.Thread(target=target, name="cellplan-deadline", daemon=True)
    thread.start()
    thread.join(seconds)
    if thread.is_alive():
        raise TimeoutError(f"no result within {seconds:g} s")
    if "error" in box:
        raise box["error"]
    return box["value"]
