"""The MQTT bridge: how late a period's state reaches a subscriber, and what the bridge costs.

A daemon on the simulated tun, stepped one control period a second on the real clock, serves
the control socket in this process; `hermsd mqtt` runs as the service runs it (its own
process, default 0.5 s poll) against a mosquitto of this script's own on a loopback port; a
subscriber here notes when each period's state arrives. Reported: the delay from the end of
a period to its state at the subscriber (p50, p99, max; the poll alone allows up to 0.5 s),
the periods whose state never came, and the CPU time of the bridge and, beside it, of the
broker that carried the same messages.

    uv run python bench/mqtt.py [--seconds 60]
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import paho.mqtt.client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from hermsd.api.link import LoopLink
from hermsd.api.server import ControlServer
from hermsd.config import read
from hermsd.runtime.assemble import assemble
from hermsd.runtime.scheduler import percentile
from hermsd.sim.clock import VirtualClock
from hermsd.sim.world import build_world

MOSQUITTO = "/usr/sbin/mosquitto"
SHIPPED = Path(__file__).resolve().parent.parent / "config" / "hermsd.yaml"


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of a live process, from /proc (clock ticks)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as scratch:
        directory = Path(scratch)
        with socket.socket() as probe:
            probe.bind(("127.0.0.1", 0))
            port = probe.getsockname()[1]
        (directory / "m.conf").write_text(
            f"listener {port} 127.0.0.1\nallow_anonymous true\npersistence false\nuser root\n"
        )
        text = SHIPPED.read_text().replace("backend: serial-rts", "backend: sim", 1)
        text = text.replace("  port: 1883", f"  port: {port}", 1)
        (directory / "hermsd.yaml").write_text(text)
        config = read.parse(text)
        clock = VirtualClock()
        world = build_world(config, clock)
        daemon = assemble(config, clock, world.sensor, world.outputs)
        daemon.start()
        link = LoopLink(daemon)
        server = ControlServer(directory / "control.sock", link.status_line)
        server.start()
        link.attach(server)
        period = config.control.period
        daemon.run(until=clock.monotonic() + period)

        broker = subprocess.Popen(
            [MOSQUITTO, "-c", directory / "m.conf"], stderr=subprocess.DEVNULL
        )
        time.sleep(0.5)  # the broker starts listening
        arrived: dict[float, float] = {}
        subscriber = mqtt.Client(CallbackAPIVersion.VERSION2, client_id="bench")

        def note_arrival(_client: mqtt.Client, _userdata: object, m: mqtt.MQTTMessage) -> None:
            arrived.setdefault(json.loads(m.payload)["t"], time.monotonic())

        subscriber.on_message = note_arrival
        subscriber.connect("127.0.0.1", port)
        subscriber.subscribe("hermsd/state", 1)
        subscriber.loop_start()
        hermsd = Path(sys.executable).parent / "hermsd"
        command: list[str | Path] = [hermsd, "mqtt", "--config", directory / "hermsd.yaml"]
        bridge = subprocess.Popen([*command, "--socket", directory / "control.sock"])
        time.sleep(2.0)  # it connects and publishes the first state

        ends: dict[float, float] = {}
        cpu_before = (cpu_seconds(bridge.pid), cpu_seconds(broker.pid))
        start = time.monotonic()
        k = 0
        while (k := k + 1) <= args.seconds:  # one period a second, on an absolute schedule
            time.sleep(max(0.0, start + k - time.monotonic()))
            daemon.run(until=clock.monotonic() + period)
            ends[json.loads(link.status_line())["t"]] = time.monotonic()
        time.sleep(1.0)  # the last state on its way
        cpu = (cpu_seconds(bridge.pid) - cpu_before[0], cpu_seconds(broker.pid) - cpu_before[1])
        bridge.terminate()
        bridge.wait(10)
        subscriber.loop_stop()
        broker.terminate()
        broker.wait(10)
        server.close()

    delays = sorted((arrived[t] - end) * 1000 for t, end in ends.items() if t in arrived)
    missed = sum(t not in arrived for t in ends)
    elapsed = args.seconds
    print(f"{len(ends)} periods (one a second for {elapsed:g} s), {missed} states missed")
    print(
        f"period end → state at the subscriber: p50 {percentile(delays, 50):.0f} ms, "
        f"p99 {percentile(delays, 99):.0f} ms, max {delays[-1]:.0f} ms"
    )
    ratio = f", bridge/broker {cpu[0] / cpu[1]:.1f}" if cpu[1] > 0 else ""
    print(
        f"CPU: bridge {cpu[0]:.2f} s ({100 * cpu[0] / elapsed:.2f} %), "
        f"broker {cpu[1]:.2f} s ({100 * cpu[1] / elapsed:.2f} %){ratio}"
    )


if __name__ == "__main__":
    main()
