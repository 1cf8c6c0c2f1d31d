"""Safety: the supervisor and its limits, latched alarms, the element watch and probe."""
