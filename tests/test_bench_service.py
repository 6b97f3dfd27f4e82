"""``orange-plan bench service``: a real server in a subprocess under a small paced fleet.

Throughput figures are the benchmark's business, not a test's (the machine is shared); this
checks that the bench runs end to end, counts what the server answered, and refuses bad
arguments.
"""

from __future__ import annotations

import json

import pytest
from conftest import run_cli

pytest.importorskip("httpx")


def test_small_fleet_is_answered_in_full():
    code, out, err = run_cli("bench", "service", "--seconds", "3", "--repeats", "1",
                             "--robots", "2", "--batch", "10", "--rate", "40",
                             "--vertices", "100", "--json")
    assert code == 0, err
    r = json.loads(out)
    assert r["errors"] == 0
    assert r["robots"] == 2 and r["batch"] == 10 and r["offered_samples_per_s"] == 40
    # a server that keeps up answers the offered rate (paced: nothing hidden in a queue)
    assert r["samples_per_s"] == pytest.approx(40, rel=0.35)
    assert 0 < r["p50_ms"] <= r["p95_ms"] <= r["p99_ms"]
    assert len(r["repeats"]) == 1 and r["repeats"][0]["samples"] > 0
    from test_json_docs import compare

    compare("bench service", r)  # docs/json.md lists exactly these keys


@pytest.mark.parametrize("flag", ["--robots", "--batch", "--repeats"])
def test_bad_arguments_are_one_line(flag):
    code, _, err = run_cli("bench", "service", flag, "0")
    assert code == 2 and flag in err and len(err.strip().splitlines()) == 1
