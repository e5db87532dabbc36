"""How late the machine itself wakes a process: the yardstick for a latency measured beside it.

A process that does nothing but sleep 5 ms at a time, in a loop, and notes how much later than
asked it woke. On a quiet machine that is a fraction of a millisecond; on one shared with other
work (more runnable threads than cores) it is what any process, the daemon's too, waits for a
core before it can even look at a request. bench.overload runs one beside the daemon in each
phase and prints it next to the requests' latencies, so a slow answer can be told apart from a
machine that gave nobody the time to answer (a run of 20 000 robots beside two other busy
processes: this process woke up to 1 s late, p99 69 ms).

    python -m bench.sleeper 10        # READY, then one JSON line after 10 s (or on EOF of stdin)
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from typing import Any

from bench.numbers import percentile

#: The nap between two looks at the clock.
NAP_S = 0.005


def measure(stop: threading.Event, seconds: float) -> dict[str, Any]:
    """Sleep in naps until ``stop`` or ``seconds``; the lateness of the wake-ups (ms)."""
    late: list[float] = []
    end = time.monotonic() + seconds
    while not stop.is_set() and time.monotonic() < end:
        t = time.monotonic()
        time.sleep(NAP_S)
        late.append(time.monotonic() - t - NAP_S)
    if not late:
        return {"n": 0}
    return {"n": len(late), **{f"p{q}_ms": round((percentile(late, q) or 0.0) * 1e3, 1) for q in (50, 99)},
            "max_ms": round(max(late) * 1e3, 1)}  # fmt: skip


class Sleeper:
    """The sleeping process, from the benchmark's side: :meth:`stop` gives its figures."""

    def __init__(self, ready_timeout: float = 60.0) -> None:
        self._result: dict[str, Any] | None = None
        self.proc = subprocess.Popen([sys.executable, "-m", "bench.sleeper", "3600"], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)  # fmt: skip
        # napping from here on: a phase's figures cover the phase, however slowly Python started
        stdout = self.proc.stdout
        assert stdout is not None
        got: list[str] = []
        reader = threading.Thread(target=lambda: got.append(stdout.readline()), daemon=True)
        reader.start()
        reader.join(ready_timeout)
        if not got or not got[0].startswith("READY"):
            self.proc.kill()
            raise RuntimeError(f"the sleeper was not ready within {ready_timeout:g} s")

    def stop(self) -> dict[str, Any]:
        """Its figures (once; later calls give the same)."""
        if self._result is None:
            try:
                out, _ = self.proc.communicate("", timeout=10.0)
                self._result = dict(json.loads(out.strip().splitlines()[-1]))
            except (subprocess.TimeoutExpired, ValueError, IndexError, OSError):
                self.proc.kill()
                self._result = {"n": 0}
        return self._result


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    seconds = float(args[0]) if args else 10.0
    stop = threading.Event()

    def watch_stdin() -> None:
        sys.stdin.read()
        stop.set()

    threading.Thread(target=watch_stdin, daemon=True).start()
    print("READY", flush=True)
    print(json.dumps(measure(stop, seconds)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
