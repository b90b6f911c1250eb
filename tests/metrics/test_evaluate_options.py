"""EvaluateOptions refuses values no score can be computed with."""

import pytest

from plantbench.errors import InputError
from plantbench.metrics.evaluate import EvaluateOptions


@pytest.mark.parametrize("bad", [dict(gt_samples=0), dict(recon_samples=-5), dict(skeleton_step=0.0),
                                 dict(skeleton_step=float("nan")), dict(breast_height=-1.0),
                                 dict(max_dist_fraction=0.0), dict(max_dist_fraction=1.5)])
def test_invalid_options_raise(bad):
    with pytest.raises(InputError, match="invalid evaluation options"):
        EvaluateOptions(**bad)


def test_defaults_and_edges_are_valid():
    EvaluateOptions()
    EvaluateOptions(gt_samples=1, recon_samples=1, breast_height=0.0, max_dist_fraction=1.0)
