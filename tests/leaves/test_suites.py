"""The leaves suites give the leaf stage the same options everywhere: the ``leaves`` method and guo's image leaves
(``leaf__`` options), on mvs depth and on the oracle's exact depth, so the report's rows differ only in the depth
and in the method that uses the leaves."""

from plantbench.suites import load_suite
from reference_impl.leaves import LeafParams


def _leaf_options(suite_name: str) -> tuple[dict, dict]:
    opts = load_suite(suite_name).method_options
    leaves = {k: v for k, v in opts["leaves"].items() if k != "depth"}
    guo = {k[len("leaf__"):]: v for k, v in opts["guo"].items() if k.startswith("leaf__")}
    return leaves, guo


def test_leaves_suites_share_the_leaf_stage_options():
    leaves, guo = _leaf_options("leaves")
    oracle_leaves, oracle_guo = _leaf_options("leaves_oracle")
    assert leaves and leaves == guo == oracle_leaves == oracle_guo
    params = LeafParams.from_options(leaves)  # every name is a LeafParams field
    assert params != LeafParams()
