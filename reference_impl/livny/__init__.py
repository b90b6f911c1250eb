"""livny (not implemented yet)."""
