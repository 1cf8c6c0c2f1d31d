"""Temperature sensors other than the LM92, each behind the loop's one `Sensor` interface.

`base.Sensor` is that interface (read, identify, wake, set_limit, limit): the LM92 driver
meets it as it is; the drivers here meet it with `SoftLimits` for the alarm limits the chips
here cannot hold, and turn every trap of their chip into a `SensorError`, never into a
temperature.
"""
