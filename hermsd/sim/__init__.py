"""Simulated hardware: the HLT model, a fake LM92 on a fake I2C bus, and a virtual clock."""
