"""What the install's kernel warm-up compiles, per group, and what it compiles twice.

Runs each group of :data:`cellplan.warmup.WARMUP_GROUPS` in its own process, all at once
(as ``python -m cellplan.warmup`` does) with one empty numba cache (a fresh
``NUMBA_CACHE_DIR``), each with a listener on numba's ``numba:compile`` event. Prints per
group the compiles and the CPU seconds, the ratio of the longest group's CPU to the
mean (1.0: the cores share the compile evenly), every kernel compiled for more than one
signature, and every (kernel, signature) compiled by more than one group (work done
twice). Takes the warm-up's own time (minutes on 2 cores).

    PYTHONPATH=src .venv/bin/python benchmarks/bench_warmup_compiles.py
"""

from __future__ import annotations

import collections
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from numba.core import event

from cellplan import warmup


class _Compiles(event.Listener):
    """Records (kernel, signature, exclusive seconds) of every real compile."""

    def __init__(self) -> None:
        self.records: list[tuple[str, str, float]] = []
        self._stack: list[list[float]] = []

    def on_start(self, ev: event.Event) -> None:
        self._stack.append([time.perf_counter(), 0.0])

    def on_end(self, ev: event.Event) -> None:
        start, nested = self._stack.pop()
        seconds = time.perf_counter() - start
        if self._stack:
            self._stack[-1][1] += seconds
        fn = ev.data["dispatcher"].py_func
        name = f"{fn.__module__}.{fn.__qualname__}"
        self.records.append((name, str(ev.data["args"]), seconds - nested))


def run_group(index: int, out: Path) -> None:
    """One group, in this process, with the listener; writes ``out`` (JSON)."""
    listener = _Compiles()
    cpu = time.process_time()
    with tempfile.TemporaryDirectory() as tmp, event.install_listener("numba:compile", listener):
        warmup._run_group(warmup.WARMUP_GROUPS[index], tmp)
    out.write_text(json.dumps({"cpu_s": time.process_time() - cpu, "compiles": listener.records}))


def main() -> None:
    with tempfile.TemporaryDirectory() as cache, tempfile.TemporaryDirectory() as tmp:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache}
        outs = [Path(tmp) / f"group{i}.json" for i in range(len(warmup.WARMUP_GROUPS))]
        jobs = [
            subprocess.Popen([sys.executable, __file__, str(i), str(out)], env=env)
            for i, out in enumerate(outs)
        ]
        if any(job.wait() != 0 for job in jobs):
            raise SystemExit("a warm-up group failed")
        groups = [json.loads(out.read_text()) for out in outs]
    seen: dict[tuple[str, str], set[int]] = collections.defaultdict(set)
    signatures: dict[str, set[str]] = collections.defaultdict(set)
    for i, group in enumerate(groups):
        kernels = [r for r in group["compiles"] if r[0].startswith("cellplan.")]
        print(
            f"group {i}: {len(group['compiles'])} compiles ({len(kernels)} cellplan kernels), "
            f"{group['cpu_s']:.1f} CPU s"
        )
        for name, sig, _ in kernels:
            seen[(name, sig)].add(i)
            signatures[name].add(sig)
    cpu = [g["cpu_s"] for g in groups]
    print(f"longest group / mean group CPU: {max(cpu) / (sum(cpu) / len(cpu)):.2f}")
    for name, sigs in sorted(signatures.items()):
        if len(sigs) > 1:
            print(f"compiled for {len(sigs)} signatures: {name}")
    for (name, _), where in sorted(seen.items()):
        if len(where) > 1:
            print(f"compiled by groups {sorted(where)}: {name}")


if __name__ == "__main__":
    if len(sys.argv) == 3:
        run_group(int(sys.argv[1]), Path(sys.argv[2]))
    else:
        main()
