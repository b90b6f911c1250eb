"""Reading and writing the on-disk contracts (docs/design.md, On-disk contracts)."""
