"""guo (not implemented yet)."""
