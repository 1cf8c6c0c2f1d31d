"""The configuration: its schema and validation, reading and watching the file."""
