"""``cellplan reproduce`` when its Dask cluster dies mid-sweep (issue 36).

A real ``dask scheduler`` and ``dask worker`` processes on 127.0.0.1 run cheap fake runs
(``sweep_cli_driver.py``: 0.05 s each). The test kills the scheduler, or every worker,
once some runs are cached. The command must exit 1 within a bounded time with one
line saying how many runs failed and why, print no traceback, and the same command run
again must answer the finished runs from the cache.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parent
DASK = str(Path(sys.executable).parent / "dask")
RUNS = 120  # fake runs; 0.05 s each, so about 6 s of work on one worker
HANG_GUARD_S = 90  # generous: a hang guard, not a speed claim


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(TESTS), "FAKE_NO_WORKER_S": "3"}


class Cluster:
    """A scheduler and workers as processes (``--no-nanny``: a killed worker stays dead)."""

    def __init__(self, port: int, log: Path) -> None:
        self.address = f"tcp://127.0.0.1:{port}"
        self.port = port
        self.log = log
        self.scheduler: subprocess.Popen[bytes] | None = None
        self.workers: list[subprocess.Popen[bytes]] = []

    def _spawn(self, *args: str) -> subprocess.Popen[bytes]:
        with self.log.open("ab") as out:
            return subprocess.Popen([DASK, *args], env=env(), stdout=out, stderr=subprocess.STDOUT)

    def start_scheduler(self) -> None:
        self.scheduler = self._spawn(
            "scheduler", "--host", "127.0.0.1", "--port", str(self.port), "--no-dashboard"
        )

    def start_workers(self, n: int) -> None:
        from distributed import Client

        self.workers += [
            self._spawn(
                "worker",
                self.address,
                "--nthreads",
                "1",
                "--no-nanny",
                "--no-dashboard",
                "--host",
                "127.0.0.1",
            )
            for _ in range(n)
        ]
        with Client(self.address, timeout="30s") as client:
            client.wait_for_workers(n, timeout=60)

    def kill_scheduler(self) -> None:
        assert self.scheduler is not None
        self.scheduler.send_signal(signal.SIGKILL)
        self.scheduler.wait(10)

    def kill_workers(self) -> None:
        for worker in self.workers:
            worker.send_signal(signal.SIGKILL)
        for worker in self.workers:
            worker.wait(10)
        self.workers = []

    def stop(self) -> None:
        for proc in [*self.workers, self.scheduler]:
            if proc is not None and proc.poll() is None:
                proc.kill()
                proc.wait(10)


@pytest.fixture
def cluster(tmp_path: Path) -> Iterator[Cluster]:
    c = Cluster(free_port(), tmp_path / "dask.log")
    c.start_scheduler()
    try:
        yield c
    finally:
        c.stop()


def reproduce_command(cluster: Cluster, out: Path) -> list[str]:
    return [
        sys.executable,
        str(TESTS / "sweep_cli_driver.py"),
        "reproduce",
        "assembly",
        "--runs",
        str(RUNS),
        "--scheduler",
        cluster.address,
        "-o",
        str(out),
    ]


def cached(out: Path) -> int:
    return sum(1 for _ in (out / "cache").rglob("*.json"))


def run_and_kill(cluster: Cluster, out: Path, kill: str) -> tuple[int, str, int]:
    """Start the sweep, kill part of the cluster once 10 runs are cached; return the
    exit status, stderr and the runs cached when it ended."""
    proc = subprocess.Popen(
        reproduce_command(cluster, out),
        env=env(),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + HANG_GUARD_S
        while cached(out) < 10:
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "the sweep cached nothing"
            time.sleep(0.05)
        if kill == "scheduler":
            cluster.kill_scheduler()
        else:
            cluster.kill_workers()
        _, err = proc.communicate(timeout=HANG_GUARD_S)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return proc.returncode, err, cached(out)


def check_one_line(err: str, why: str, done: int, out: Path) -> None:
    assert "Traceback" not in err and "distributed." not in err, err
    errors = [line for line in err.splitlines() if line.startswith("error:")]
    assert len(errors) == 1, err
    assert errors[0] == (
        f"error: {RUNS - done} of {RUNS} runs failed ({why}); report written: "
        f"{out / 'index.html'}; {done} runs cached in {out / 'cache'}: run the same "
        "command to retry the rest"
    ), err
    # the only other line is the progress bar's last state
    assert len(err.strip().splitlines()) <= 2, err


def check_resume(cluster: Cluster, out: Path, done: int) -> None:
    again = subprocess.run(
        reproduce_command(cluster, out),
        env=env(),
        capture_output=True,
        text=True,
        timeout=HANG_GUARD_S,
    )
    assert again.returncode == 0, again.stderr
    assert again.stdout.strip() == f"report written: {out / 'index.html'}"
    meta = json.loads((out / "data" / "assembly.sleepy.json").read_text())
    assert meta["runs_cached"] == done and meta["runs_failed"] == 0
    assert cached(out) == RUNS


def test_killing_the_scheduler_mid_sweep_exits_1_in_one_line_and_resumes(
    cluster: Cluster, tmp_path: Path
) -> None:
    cluster.start_workers(1)
    out = tmp_path / "out"
    code, err, done = run_and_kill(cluster, out, "scheduler")
    assert code == 1, err
    assert 10 <= done < RUNS
    check_one_line(err, "the Dask scheduler was lost", done, out)

    cluster.stop()
    cluster.start_scheduler()  # the same address, as the same command needs
    cluster.start_workers(1)
    check_resume(cluster, out, done)


@pytest.mark.slow  # a real cluster; the rule is covered fast below (and the scheduler test)
def test_killing_every_worker_mid_sweep_ends_in_bounded_time_and_resumes(
    cluster: Cluster, tmp_path: Path
) -> None:
    cluster.start_workers(2)
    out = tmp_path / "out"
    code, err, done = run_and_kill(cluster, out, "workers")
    assert code == 1, err
    assert 10 <= done < RUNS
    check_one_line(err, "no Dask worker was alive for 3 s", done, out)

    cluster.start_workers(1)
    check_resume(cluster, out, done)


# --- the same rules without a cluster (fast; the tests above are the real thing) ----------------


class _Future:
    """A Dask future whose run never finishes (its worker is gone)."""

    status = "pending"

    def done(self) -> bool:
        return False


class _Client:
    """A client whose scheduler answers, or is lost, with no worker."""

    def __init__(self, status: str) -> None:
        self.status = status

    def scheduler_info(self) -> dict[str, dict[str, object]]:
        return {"workers": {}}


@pytest.mark.parametrize(
    ("status", "why"),
    [("running", "no Dask worker was alive for 0.05 s"), ("closed", "the Dask scheduler was lost")],
)
def test_runs_still_out_fail_in_bounded_time_when_the_cluster_is_gone(
    status: str, why: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    import distributed

    from cellplan import experiments as ex
    from cellplan.core import RunSpec

    monkeypatch.setattr(ex, "NO_WORKER_TIMEOUT_S", 0.05)
    monkeypatch.setattr(ex, "POLL_S", 0.01)
    monkeypatch.setattr(
        distributed, "wait", lambda futures, timeout, return_when: time.sleep(timeout)
    )
    batches = {
        _Future(): [ex._Pending(0, i, RunSpec("x", {"n": i}, i), f"k{i}") for i in range(3)],
        _Future(): [ex._Pending(0, 3, RunSpec("x", {"n": 3}, 3), "k3")],
    }
    rows: list[dict[str, object]] = []
    start = time.monotonic()
    lost = ex._collect(_Client(status), batches, lambda item, row: rows.append(row), None, None)
    assert lost == why
    assert time.monotonic() - start < 30  # a hang guard: the no-worker wait is 0.05 s
    assert [r["run_status"] for r in rows] == [ex.FAILED] * 4
    assert {r["run_error"] for r in rows} == {f"dask: not run: {why}"}
