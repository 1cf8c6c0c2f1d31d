"""hermsd: holds the water of a HERMS Hot Liquid Tun at its setpoint, safely."""

__version__ = "0.1.0"
