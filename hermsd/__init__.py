"""hermsd: holds the water of a HERMS Hot Liquor Tank at its setpoint, safely."""

__version__ = "0.1.0"
