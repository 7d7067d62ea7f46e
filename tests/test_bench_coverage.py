"""The coverage matrix's verdict (benchmarks/bench_coverage.py) on campaigns of known outcome."""

import importlib.util
from pathlib import Path

import pytest

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_coverage.py"


@pytest.fixture(scope="module")
def bc():
    spec = importlib.util.spec_from_file_location("bench_coverage", _PATH)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _campaign(errs: list[float], u: float = 1.0, misfit: bool = False) -> dict:
    m = {"crash": 0, "misfit": int(misfit), "flagged": int(misfit)}
    for j, e in enumerate(errs):
        m[f"err:p{j}"] = e
        m[f"ref:p{j}"] = 100.0
        m[f"U:p{j}"] = u
    return m


def test_a_row_that_covers_is_ok(bc):
    camps = [_campaign([0.5 * (-1) ** i, 0.4, -0.3]) for i in range(20)]
    st = bc._stats(camps)
    assert (st["inside"], st["determined"]) == (60, 60)
    assert st["hi"] == 1.0
    assert bc._verdict(camps, st) == "ok"


def test_misses_only_where_the_campaign_says_u_is_a_lower_bound_are_flagged(bc):
    camps = [_campaign([0.5, -0.4, 0.3]) for _ in range(14)]
    camps += [_campaign([2.5, -0.4, 3.0], misfit=True) for _ in range(6)]
    st = bc._stats(camps)
    assert st["inside"] == 48 and st["hi"] < 0.95
    assert bc._verdict(camps, st) == "flagged"


def test_misses_in_campaigns_that_say_nothing_are_short(bc):
    camps = [_campaign([0.5, -0.4, 0.3], misfit=True) for _ in range(14)]
    camps += [_campaign([2.5, -0.4, 3.0]) for _ in range(6)]
    assert bc._verdict(camps, bc._stats(camps)) == "SHORT"


def test_a_loose_u_passes_only_when_every_campaign_says_so(bc):
    loose = [_campaign([0.01 * (-1) ** i, 0.02, -0.01]) for i in range(20)]
    st = bc._stats(loose)
    assert st["u_rms"] > 3.0 and st["hi"] == 1.0
    assert bc._verdict(loose, st) == "LOOSE"
    loose[3]["misfit"] = 1
    assert bc._verdict(loose, st) == "LOOSE"
    for m in loose:
        m["misfit"] = 1
    assert bc._verdict(loose, st) == "flagged"


def test_the_bootstrap_bound_counts_a_campaign_once(bc):
    # the same 10 misses in 200 parameters: spread over 10 campaigns, or three at a time
    # in few campaigns (a lobe's parameters miss together): the grouped row is less certain
    spread = [_campaign([2.0] + [0.1] * 9) for _ in range(10)]
    spread += [_campaign([0.1] * 10) for _ in range(10)]
    grouped = [_campaign([2.0] * 5 + [0.1] * 5) for _ in range(2)]
    grouped += [_campaign([0.1] * 10) for _ in range(18)]
    a, b = bc._stats(spread), bc._stats(grouped)
    assert a["inside"] == b["inside"] == 190
    assert b["hi"] > a["hi"]
