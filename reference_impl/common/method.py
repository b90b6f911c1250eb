"""What the reference points methods share as registered methods: options that are the fields of one parameter
dataclass (``options_model``), checked before any work and built for a run from the same model."""

from __future__ import annotations

from plantbench.schemas import params_from_options

__all__ = ["ParamsMethod"]


class ParamsMethod:
    """A ``points`` method whose options are the fields of ``options_model`` (a frozen dataclass); subclasses set
    ``name`` and ``options_model`` and read their parameters with :meth:`params`."""

    name: str
    inputs = "points"
    options_model: type

    def check_options(self, options: dict) -> None:
        """Raise InputError on an unknown or invalid option (the planner calls it before any job runs)."""
        self.params(options)

    def params(self, options: dict):
        """The run's parameters: ``options_model`` with ``options`` (a suite's ``[method_options.NAME]``) set."""
        return params_from_options(self.options_model, options, method=self.name)
