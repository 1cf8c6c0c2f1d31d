"""Commissioning: measuring the tun (a step test, a relay test, a brew day's log) and turning
its model into the config's settings: `hermsd tune`, and the fit `replay --what-if` shares."""
