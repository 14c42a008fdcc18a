"""The seekers' benchmark (``benchmarks/convergence.py``): what it refuses, and the search's own
t_99 it reports beside t_99, checked against its definition on the user's true power."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from sessions.simulation import run_simulation, score
from testing.benchmarks import ROOT, load

convergence = load("convergence")
SCRIPT = ROOT / "convergence.py"


@pytest.mark.parametrize(
    ("args", "names"),
    [
        (["--users", "8"], "--users"),  # a group missing: the table had min() of nothing
        (["--populations", "0"], "--populations"),
        (["--seekers", "sweep,simplex"], "simplex"),
    ],
)
def test_bad_arguments_are_refused_in_one_line(args: list[str], names: str) -> None:
    out = subprocess.run(
        [sys.executable, str(SCRIPT), *args, "--json"],
        check=False,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 2
    assert out.stdout == ""
    last = out.stderr.strip().splitlines()[-1]
    assert last.startswith("convergence.py: error:") and names in last


def test_each_population_is_drawn_with_its_own_seed() -> None:
    a, b = convergence.population(12, 14), convergence.population(12, 15)
    assert {p["population"] for p in a} == {14} and {p["population"] for p in b} == {15}
    assert [p["bracket"] for p in a] != [p["bracket"] for p in b]
    assert [p["bracket"] for p in a] == [p["bracket"] for p in convergence.population(12, 14)]


@pytest.mark.parametrize("pid", [10, 11])  # #11 of seed 14: its tracker dips after the search
def test_the_searchs_own_t99_holds_until_wd_is_at_its_vertex(pid: int) -> None:
    person = convergence.population(12, 14)[pid]
    result = run_simulation(convergence.session_config(person, "sweep"))
    s = score(result)
    ts = convergence.t_99_search(result, s)
    t, wd = result.column("t"), result.column("wd")
    ratio = result.user.power_ratio(wd, t)
    tc, wc = s["t_converged"], s["wd_converged"]
    assert tc is not None
    arrived = t[(t >= tc) & (np.abs(wd - wc) <= 0.02 * wc)]
    if ts is None:  # the search arrived outside the band
        assert ratio[np.searchsorted(t, arrived[0])] < 0.99
        return
    held = (t >= ts - 1e-9) & (t <= arrived[0])
    assert ratio[held].min() >= 0.99
    assert ratio[np.searchsorted(t, ts) - 1] < 0.99  # and not a sample sooner
    if s["t_99"] is not None:
        assert ts <= s["t_99"]  # the whole session's hold includes the search's
