"""mvs (not implemented yet)."""
