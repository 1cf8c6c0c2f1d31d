"""`hermsd web` and `hermsd mqtt`: the services beside the daemon, each a client of its
control socket."""

from __future__ import annotations

import argparse
import signal

from hermsd.cli.common import (
    UserError,
    config_path,
    control_socket,
)
from hermsd.config import read
from hermsd.runtime.instance import InstanceError


def cmd_web(args: argparse.Namespace) -> int:
    try:
        from hermsd.web import main as web
    except ImportError as error:
        raise UserError(
            f"hermsd web needs the web extra ({error.name} is not installed): "
            "install hermsd with `--extra web` (uv) or as `hermsd[web]` (pip)"
        ) from None
    try:
        if args.hash_password:
            return web.print_hash()
        path = config_path(args.config, simulate=False)
        assert path is not None
        return web.run(read.load(path), control_socket(args.socket), args.listen)
    except web.WebSetupError as error:
        raise UserError(str(error)) from None


def cmd_mqtt(args: argparse.Namespace) -> int:
    """Serve the bridge until SIGTERM or Ctrl-C; it leaves "offline" on the broker."""
    try:
        from hermsd.mqtt.bridge import Bridge, BridgeError
    except ModuleNotFoundError as error:
        if not (error.name or "").startswith("paho"):
            raise
        raise UserError(
            "the MQTT bridge needs paho-mqtt: install hermsd with its mqtt extra "
            "(uv sync --extra mqtt; uv tool install --with paho-mqtt)"
        ) from None
    path = config_path(args.config, simulate=False)
    assert path is not None
    config = read.load(path)
    try:
        programs = args.programs or path.parent / "programs"
        bridge = Bridge(config, control_socket(args.socket), programs=programs)
    except BridgeError as error:
        raise UserError(str(error)) from None
    for signum in (signal.SIGTERM, signal.SIGINT):
        signal.signal(signum, lambda _signum, _frame: bridge.stop())
    try:
        bridge.run()
    except InstanceError as error:
        raise UserError(str(error)) from None
    return 0
