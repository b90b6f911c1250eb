"""leaves (not implemented yet)."""
