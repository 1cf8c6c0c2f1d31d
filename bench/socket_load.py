"""The control socket under load: do 1,000 status requests a second delay the control loop?

The real loop (monotonic clock, sleeping for real, the MCAP recorder beside it) runs on the
simulated tun at the rates of bench/timing.py (0.5 s periods, 0.1 s SSR windows, manual
50 %: one timed edge per window), with the control socket served as `hermsd run` serves it.
Rows: no clients, then a client process that opens a connection, asks `status` and reads the
reply 1,000 times a second (a new connection each time, as `hermsd status` does); each with
the loop at ordinary priority and at SCHED_FIFO 10 (as on the Pi; needs root or an
RLIMIT_RTPRIO of 10). Reported: control-period lateness and SSR-edge error p50/p99/max,
requests answered, the rate reached and the client's round trip. Goals: period p99 ≤ 5 ms,
edge p99 ≤ 10 ms.

    uv run python bench/socket_load.py [--seconds 60] [--rate 1000] [--write]

With --program the client sends, instead of `status`, the costliest `program start` a line
can hold (bench/program_parse.py's 64 KiB refused program), as fast as it is answered up to
the rate; the server thread checks each while the loop runs. (Its rows are printed, not
written: bench/RESULTS.md compares them between two builds.)

(Not `bench/socket.py`: a script's directory comes first on sys.path, and a file named
socket.py there would stand in for the standard library's socket module.)
"""

from __future__ import annotations

import argparse
import contextlib
import json
import multiprocessing
import os
import socket
import sys
import tempfile
import time
from collections.abc import Iterator
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from program_parse import longest_refused  # bench/program_parse.py, beside this file
from timing import measure, timing_table  # bench/timing.py, beside this file

from hermsd.api.link import LoopLink
from hermsd.api.server import ControlServer
from hermsd.hardware.realtime import LOOP_PRIORITY
from hermsd.runtime.daemon import Daemon
from hermsd.runtime.scheduler import percentile

STATUS = b'{"v": 1, "cmd": "status"}\n'
PROGRAM = {"v": 1, "cmd": "program", "action": "start", "program": longest_refused()}
PROGRAM_START = json.dumps(PROGRAM).encode() + b"\n"


def hammer(path: str, rate: float, stop_at: float, request: bytes, results: Connection) -> None:
    """`rate` requests a second on fresh connections, on an absolute schedule."""
    answer = b'"ok": true' if request == STATUS else b'"error": "program: '
    latencies: list[float] = []
    failures: dict[str, int] = {}
    start = time.monotonic()
    k = 0
    while True:
        due = start + k / rate
        if due >= stop_at or time.monotonic() >= stop_at:  # behind the rate: stop on time
            break
        delay = due - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        k += 1
        sent = time.monotonic()
        try:
            with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
                sock.settimeout(2.0)
                sock.connect(path)
                sock.sendall(request)
                reply = b""
                while not reply.endswith(b"\n"):
                    chunk = sock.recv(65536)
                    if not chunk:
                        break
                    reply += chunk
            if answer not in reply:
                why = reply.decode(errors="replace").strip() or "closed without a reply"
                failures[why] = failures.get(why, 0) + 1
                continue
        except OSError as error:
            why = type(error).__name__
            failures[why] = failures.get(why, 0) + 1
            continue
        latencies.append(time.monotonic() - sent)
    results.send((latencies, failures, time.monotonic() - start))
    results.close()


@contextlib.contextmanager
def served(
    daemon: Daemon, path: Path, rate: float | None, seconds: float, request: bytes
) -> Iterator[None]:
    """The control socket beside the loop, and (with a rate) a client process hammering it."""
    link = LoopLink(daemon)
    server = ControlServer(path, link.status_line, link.history_line)
    server.start()
    link.attach(server)
    client = None
    receiver, sender = multiprocessing.Pipe(duplex=False)
    if rate is not None:
        stop_at = time.monotonic() + seconds
        client = multiprocessing.Process(
            target=hammer, args=(str(path), rate, stop_at, request, sender)
        )
        client.start()
    try:
        yield
    finally:
        if client is not None:
            latencies, failures, elapsed = receiver.recv()
            client.join()
            LOAD.update(_load_figures(sorted(latencies), failures, elapsed))
        server.close()


LOAD: dict[str, float] = {}


def _load_figures(
    latencies: list[float], failures: dict[str, int], elapsed: float
) -> dict[str, float]:
    for why, count in failures.items():
        print(f"failed {count}×: {why}", flush=True)
    return {
        "answered": len(latencies),
        "failed": sum(failures.values()),
        "rate": len(latencies) / elapsed,
        "rtt_p50_ms": percentile(latencies, 50) * 1e3,
        "rtt_p99_ms": percentile(latencies, 99) * 1e3,
        "rtt_max_ms": latencies[-1] * 1e3,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--rate", type=float, default=1000.0, help="status requests a second")
    parser.add_argument("--dir", type=Path, default=Path("/var/tmp"), help="disk for the logs")
    parser.add_argument("--write", action="store_true", help="update bench/RESULTS.md (status)")
    parser.add_argument("--program", action="store_true", help="send 64 KiB program starts")
    args = parser.parse_args()
    realtime_allowed = os.geteuid() == 0
    request, loaded = (
        (PROGRAM_START, f"≤ {args.rate:.0f} program starts/s")
        if args.program
        else (STATUS, f"{args.rate:.0f} status/s")
    )
    runs = [("no clients", None, False), (loaded, args.rate, False)]
    if realtime_allowed:
        runs += [(f"{name}, real-time loop", rate, True) for name, rate, _ in runs]
    rows: dict[str, dict[str, float]] = {}
    with tempfile.TemporaryDirectory(dir=args.dir, prefix="hermsd-socket-") as scratch:
        for index, (name, rate, realtime) in enumerate(runs):
            LOAD.clear()
            path = Path(scratch, f"control{index}.sock")

            def beside(daemon: Daemon, path: Path = path, rate: float | None = rate) -> Any:
                return served(daemon, path, rate, args.seconds, request)

            rows[name] = measure(args.seconds, Path(scratch, f"log{index}"), realtime, beside)
            rows[name].update(LOAD)
            print(name, rows[name], flush=True)
    table = _table(rows) + "\n\n" + _ratios(rows, runs[1][0])
    print(table)
    if args.write and not args.program:
        _write_results(args.seconds, args.rate, args.dir, table)
    return 0


def _write_results(seconds: float, rate: float, directory: Path, table: str) -> None:
    import sections  # bench/sections.py, beside this file

    text = (
        f"As root ({seconds:.0f} s per row, {rate:.0f} status requests a second, "
        f"{os.cpu_count()} cores shared with other work, logs on {directory}). The real loop "
        "on the simulated tun at bench/timing.py's rates (0.5 s periods, 0.1 s SSR windows, "
        "one timed edge per window), the socket served beside it as `hermsd run` serves "
        "it; the client is another process opening a new connection per request. The "
        f"real-time rows run the loop thread at SCHED_FIFO {LOOP_PRIORITY}, as on the Pi. "
        "Goals: period p99 ≤ 5 ms, edge p99 ≤ 10 ms. CPU is the whole daemon process's "
        "(its server thread's share is the difference between rows). Other processes may "
        "run on the cores meanwhile, so a ratio below 1 means no measurable cost, not a "
        "gain.\n\n" + table + "\n"
    )
    sections.write("## Control socket: the loop under 1,000 status requests a second", text)


def _ratios(rows: dict[str, dict[str, float]], loaded_name: str) -> str:
    """The loaded rows' p99s over the unloaded ones' of the same priority."""
    lines = []
    for suffix in ("", ", real-time loop"):
        quiet, loaded = rows.get(f"no clients{suffix}"), rows.get(f"{loaded_name}{suffix}")
        if quiet is None or loaded is None:
            continue
        period = loaded["period_p99_ms"] / max(quiet["period_p99_ms"], 1e-9)
        edge = loaded["edge_p99_ms"] / max(quiet["edge_p99_ms"], 1e-9)
        loop = "real-time" if suffix else "ordinary"
        lines.append(
            f"{loop.capitalize()} loop, with the clients over without: period p99 ×{period:.2f}, "
            f"edge p99 ×{edge:.2f}."
        )
    return " ".join(lines)


def _table(rows: dict[str, dict[str, float]]) -> str:
    more = ["overruns", "CPU %", "answered", "failed", "rate /s", "round trip p50/p99/max ms"]
    cells = {
        name: f"{r['overruns']:.0f} | {r['cpu_percent']:.1f} | "
        + (
            f"{r['answered']:.0f} | {r['failed']:.0f} | {r['rate']:.0f} | "
            f"{r['rtt_p50_ms']:.2f} / {r['rtt_p99_ms']:.2f} / {r['rtt_max_ms']:.2f}"
            if "answered" in r
            else "– | – | – | –"
        )
        for name, r in rows.items()
    }
    return timing_table("clients", more, rows, cells)


if __name__ == "__main__":
    sys.exit(main())
