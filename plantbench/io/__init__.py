"""Reading and writing the on-disk contracts (DESIGN.md section 3)."""
