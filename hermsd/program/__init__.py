"""Mash programs: named steps of setpoints and holds that the daemon runs through a brew day."""
