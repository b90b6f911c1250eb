"""Each metrics job names the capture its method read, whose observed wood splits observation from inference."""

from plantbench.runner.plan import make_plan
from plantbench.suites import load_suite


def _observed_from(suite_name: str, methods: list[str]) -> dict[str, set]:
    plan = make_plan(load_suite(suite_name), methods)
    by_key = {c.metrics_key: c.method for c in plan.cells}
    out: dict[str, set] = {}
    for job in plan.jobs.values():
        if job.kind == "metrics":
            out.setdefault(by_key[job.key], set()).add(job.params["observed_from"])
    return out


def test_a_scan_suite_scores_against_the_scan_and_a_view_suite_against_the_views():
    assert _observed_from("scan", ["gt", "livny"]) == {"gt": {"scan"}, "livny": {"scan"}}
    assert _observed_from("quick", ["gt", "livny"]) == {"gt": {None}, "livny": {None}}
