"""Reconstruction methods shipped with plantbench, registered through the plantbench.methods entry point."""
