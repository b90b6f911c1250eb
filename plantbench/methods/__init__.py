"""Method API: what a reconstruction method is, and how one is run (docs/design.md, Method API and isolation).

The registry (:data:`plantbench.registry.methods`) loads every method, shipped or third-party, from the entry
point group ``plantbench.methods``.
"""

from plantbench.methods.api import INPUT_KINDS, ExternalCommand, Method, method_from_spec

__all__ = ["Method", "ExternalCommand", "INPUT_KINDS", "method_from_spec"]
