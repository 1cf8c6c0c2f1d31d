"""`hermsd mqtt`: the daemon's state on an MQTT broker, with Home Assistant's discovery, and
its setpoint and mode commands back through the control socket (docs/mqtt.md)."""
