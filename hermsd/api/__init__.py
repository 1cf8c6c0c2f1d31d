"""The control socket: how `hermsd status|set|reset-alarm` (and later the web page and the
MQTT bridge) talk to the running daemon. `protocol` is the wire format, `server` the daemon's
side, `link` what the control loop does with it at each period boundary, `client` the
commands' side."""
