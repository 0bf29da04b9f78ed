"""Pipeline stages: pure functions from arrays/dataclasses to arrays/dataclasses (no I/O)."""
