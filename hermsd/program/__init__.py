"""The mash program: a file of steps (`model`), a pure runner that turns it into the setpoint
(`runner`), its progress kept across restarts (`store`), and the daemon's side (`driver`)."""
