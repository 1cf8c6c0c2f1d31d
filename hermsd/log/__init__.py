"""The log: the flight recorder, the log reader, replay, the plot."""
