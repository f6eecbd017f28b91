"""``--scheduler`` against servers that are not Dask (issue 16): one line, exit 2, no hang.

Each server runs in a thread on 127.0.0.1 and does one thing: answer like HTTP, send
0xff bytes, close at once, accept and never answer, or imitate Dask's handshake and
then fall silent. The probe's deadline is shortened to keep the tests quick.
"""

from __future__ import annotations

import socket
import struct
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

import fake_sweep_experiments as fake
from cellplan import experiments as ex
from cellplan import scheduler
from cellplan.errors import ArgumentError

Behaviour = Callable[[socket.socket], None]


def http(conn: socket.socket) -> None:
    conn.sendall(b"HTTP/1.1 200 OK\r\nContent-Length: 2\r\n\r\nhi")


def ones(conn: socket.socket) -> None:
    conn.sendall(b"\xff" * 4096)


def close_at_once(conn: socket.socket) -> None:
    pass


def silent(conn: socket.socket) -> None:
    threading.Event().wait(30)


def half_message(conn: socket.socket) -> None:
    conn.sendall(struct.pack("Q", 58) + b"\x01" + b"\x00" * 7)


def dask_lookalike(conn: socket.socket) -> None:
    """Dask's handshake (a msgpack mapping in Dask's framing), then nothing."""
    # msgpack {"compression": None, "python": [3, 11, 7], "pickle-protocol": 5}
    hello = b"\x83\xabcompression\xc0\xa6python\x93\x03\x0b\x07\xafpickle-protocol\x05"
    conn.sendall(struct.pack("3Q", 16 + len(hello), 1, len(hello)) + hello)
    threading.Event().wait(30)


@pytest.fixture
def serve() -> Iterator[Callable[[Behaviour], str]]:
    """Start a one-behaviour server; yields a function returning its tcp:// address."""
    socks: list[socket.socket] = []

    def start(behaviour: Behaviour) -> str:
        srv = socket.socket()
        srv.bind(("127.0.0.1", 0))
        srv.listen(8)
        socks.append(srv)

        def loop() -> None:
            while True:
                try:
                    conn, _ = srv.accept()
                except OSError:
                    return
                socks.append(conn)
                threading.Thread(target=_serve_one, args=(conn, behaviour), daemon=True).start()

        threading.Thread(target=loop, daemon=True).start()
        return f"tcp://127.0.0.1:{srv.getsockname()[1]}"

    yield start
    for s in socks:
        s.close()


def _serve_one(conn: socket.socket, behaviour: Behaviour) -> None:
    try:
        behaviour(conn)
    except OSError:
        pass
    finally:
        conn.close()


@pytest.mark.parametrize(
    ("behaviour", "why"),
    [
        (http, "are not a Dask message"),
        (ones, "are not a Dask message"),
        (close_at_once, "closed the connection"),
        (silent, "sent nothing"),
        (half_message, "stopped mid-message"),
    ],
)
def test_a_server_that_is_not_dask_is_refused_by_the_probe(
    serve: Callable[[Behaviour], str], behaviour: Behaviour, why: str
) -> None:
    address = serve(behaviour)
    with pytest.raises(ArgumentError) as info:
        scheduler.probe_scheduler(address, timeout=1.0)
    (problem,) = info.value.problems
    assert problem.field == "--scheduler" and "\n" not in problem.message
    assert (
        problem.message.startswith(f"{address}: not a Dask scheduler (") and why in problem.message
    )


def test_a_lookalike_that_falls_silent_is_cut_off_by_the_client_deadline(
    serve: Callable[[Behaviour], str], monkeypatch: pytest.MonkeyPatch
) -> None:
    address = serve(dask_lookalike)
    scheduler.probe_scheduler(address, timeout=1.0)  # the handshake looks right
    monkeypatch.setattr(scheduler, "PROBE_TIMEOUT_S", 1.0)
    with pytest.raises(ArgumentError, match="not a Dask scheduler") as info:
        scheduler.connect_client(address, timeout=2.0)
    assert info.value.problems[0].field == "--scheduler"


def test_the_sweep_refuses_junk_before_any_run(
    serve: Callable[[Behaviour], str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(scheduler, "PROBE_TIMEOUT_S", 1.0)
    address = serve(http)
    with pytest.raises(ArgumentError, match="not a Dask scheduler"):
        ex.run_sweep([fake.grid()], 1, False, tmp_path, progress=False, scheduler=address)
    assert not (tmp_path / "cache").exists()  # nothing ran


@pytest.mark.parametrize(
    "address", ["tls://127.0.0.1:8786", "ucx://h:8786", "ws://h:1", "wss://h:1"]
)
def test_other_protocols_are_refused_up_front(address: str) -> None:
    with pytest.raises(ArgumentError, match=r"not supported.*tcp://HOST:PORT"):
        scheduler.check_scheduler_address(address)


def test_the_command_line_prints_one_line_and_exits_2(
    serve: Callable[[Behaviour], str], tmp_path: Path
) -> None:
    address = serve(ones)
    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "cellplan.cli",
            "reproduce",
            "assembly",
            "--quick",
            "--scheduler",
            address,
            "-o",
            str(tmp_path / "r"),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert res.returncode == 2, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and f"--scheduler: {address}: not a Dask scheduler (" in lines[0]
    tls = subprocess.run(
        [
            sys.executable,
            "-m",
            "cellplan.cli",
            "reproduce",
            "--scheduler",
            "tls://127.0.0.1:1",
            "-o",
            str(tmp_path / "t"),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert tls.returncode == 2 and len(tls.stderr.strip().splitlines()) == 1, tls.stderr
    assert not (tmp_path / "t").exists()


def test_a_real_scheduler_passes_the_probe() -> None:
    from distributed import LocalCluster

    with LocalCluster(
        n_workers=0, processes=False, protocol="tcp://", host="127.0.0.1", dashboard_address=None
    ) as cluster:
        scheduler.probe_scheduler(cluster.scheduler_address)
        client = scheduler.connect_client(cluster.scheduler_address)
        client.close()
