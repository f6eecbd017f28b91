"""Ctrl-C ends every command with status 130 and one line, never 0 and a traceback (issue 36)."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from cellplan import cli


class _Finaliser:
    """An object whose finaliser is interrupted: Python prints and swallows that."""

    def __del__(self) -> None:
        raise KeyboardInterrupt


def test_an_interrupt_swallowed_by_a_finaliser_still_ends_in_130(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    def command() -> None:
        _Finaliser()  # dropped at once: its KeyboardInterrupt is "ignored"
        sys.exit(0)

    monkeypatch.setattr(cli, "_dispatch", command)
    with pytest.raises(SystemExit) as exc:
        cli.main()
    assert exc.value.code == 130
    err = capsys.readouterr().err
    assert err.strip() == "interrupted"
    assert "Traceback" not in err and "Exception ignored" not in err


def test_main_leaves_the_process_handlers_as_it_found_them(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    handler, hook = signal.getsignal(signal.SIGINT), sys.unraisablehook
    monkeypatch.setattr(cli, "_dispatch", lambda: sys.exit(0))
    with pytest.raises(SystemExit):
        cli.main()
    assert signal.getsignal(signal.SIGINT) is handler and sys.unraisablehook is hook


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_ctrl_c_during_adapt_is_130_and_one_line(tmp_path: Path) -> None:
    db = tmp_path / "exp.sqlite"
    proc = subprocess.Popen(
        [sys.executable, "-m", "cellplan.cli", "adapt", "adaptive_fig4", "--db", str(db),
         "-o", str(tmp_path / "out")],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        # A suite started in the background of a non-interactive shell (nohup make test &)
        # hands its children SIGINT ignored, which the CLI keeps on purpose: give this
        # child the disposition of a terminal's foreground job.
        preexec_fn=_default_sigint,
    )  # fmt: skip
    deadline = time.monotonic() + 120
    while proc.poll() is None and not Path(f"{db}.lock").exists():
        assert time.monotonic() < deadline, "the run never took its database"
        time.sleep(0.005)
    assert proc.poll() is None, "the run ended before it could be interrupted"
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert err.strip().splitlines() == ["interrupted"]
    assert not (tmp_path / "out").exists()  # nothing half-written
