"""The daemon's loop, its scheduler and clock, and what runs beside it."""
