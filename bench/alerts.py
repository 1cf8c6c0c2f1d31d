"""What alerts cost the control loop: the hand-over, and the worker's children beside it.

`Alerts.send` is all the loop thread does for an event: its cost per call (median of many)
when there is no command, when the rate limit holds the event back, and when it is queued,
against `queue.Queue.put_nowait` (what the recorder's `write` does) in the same run. Then the
lateness of a 10 ms ticker on the calling thread (it shares the GIL with the worker) while
the worker starts commands back to back, against the same ticker idle.

    uv run python bench/alerts.py
"""

from __future__ import annotations

import platform
import queue
import statistics
import sys
import threading
import time
from collections.abc import Callable

from hermsd.config.schema import AlertsConfig
from hermsd.runtime.alerts import Alerts, Event

CALLS = 20_000
TICK = 0.01
TICKS = 300
EVENT = Event("alarm_raised", "ALARM overtemp: bench; heater off", "HLT", 0, kind="overtemp")


def per_call_us(call: Callable[[int], None]) -> float:
    """Median over 5 rounds of the mean time of one call (given the call's number), in µs."""
    rounds = []
    for r in range(5):
        began = time.perf_counter()
        for i in range(r * CALLS, (r + 1) * CALLS):  # t only moves forward, as the loop's
            call(i)
        rounds.append((time.perf_counter() - began) / CALLS * 1e6)
    return statistics.median(rounds)


def send_costs() -> dict[str, float]:
    said: list[str] = []
    off = Alerts(AlertsConfig(command=None), said.append)
    limited = Alerts(AlertsConfig(command=("true",), min_interval=1e9), said.append)
    limited.send(EVENT, 0.0)  # the first goes on the queue; the rest are held back
    queued = Alerts(AlertsConfig(command=("true",), min_interval=0.0), said.append, CALLS * 5)
    peer: queue.Queue[object] = queue.Queue(CALLS * 5)
    return {
        "send, no command": per_call_us(lambda i: off.send(EVENT, float(i))),
        "send, held back by min_interval": per_call_us(lambda i: limited.send(EVENT, float(i))),
        "send, queued": per_call_us(lambda i: queued.send(EVENT, float(i))),
        "peer: Queue.put_nowait": per_call_us(lambda i: peer.put_nowait(EVENT)),
    }


def ticker_lateness_ms(busy: threading.Event | None) -> tuple[float, float, float]:
    """p50, p99 and max lateness of a 10 ms ticker, in ms."""
    late = []
    deadline = time.monotonic() + TICK
    for _ in range(TICKS):
        time.sleep(max(0.0, deadline - time.monotonic()))
        late.append((time.monotonic() - deadline) * 1e3)
        deadline += TICK
    if busy is not None:
        busy.set()
    late.sort()
    return late[len(late) // 2], late[int(len(late) * 0.99)], late[-1]


def main() -> None:
    print(f"python {platform.python_version()} on {platform.machine()}, {sys.platform}")
    for name, us in send_costs().items():
        print(f"{name:34} {us:7.2f} µs per call")
    idle = ticker_lateness_ms(None)
    done = threading.Event()
    dropped: list[str] = []
    alerts = Alerts(AlertsConfig(command=("true",), min_interval=0.0), dropped.append, 4)
    alerts.start()

    def feed() -> None:  # faster than the worker can start commands: it never idles
        while not done.is_set():
            alerts.send(EVENT, 0.0)
            done.wait(0.002)

    feeder = threading.Thread(target=feed)
    feeder.start()
    busy = ticker_lateness_ms(done)
    feeder.join()
    alerts.close(10.0)
    for name, (p50, p99, worst) in (("idle", idle), ("worker starting commands", busy)):
        print(f"10 ms ticker, {name:26} p50 {p50:.3f}  p99 {p99:.3f}  max {worst:.3f} ms")
    print(f"events dropped by the full queue meanwhile (the worker was never idle): {len(dropped)}")


if __name__ == "__main__":
    main()
