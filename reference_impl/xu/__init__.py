"""xu (not implemented yet)."""
