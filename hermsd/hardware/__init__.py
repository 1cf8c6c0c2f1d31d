"""The hardware: sensor, outputs, SSR planner, safe-off, real-time priority."""
