"""`ergoseek simulate` and `ergoseek reproduce`, run as a user runs them."""

from __future__ import annotations

import itertools
import json
from collections.abc import Callable
from pathlib import Path

import pytest

from sessions.telemetry import csv_header
from testing.cli import ergoseek

SCENARIO = """
duration = 12.0
rate = 500.0
seed = 3
[user]
kind = "linear"
tau0 = 2.0
wmax = 6.0
[seeker]
kind = "parabolic"
bracket = [1.0, 2.5, 4.0]
objective = "surrogate"
"""


def test_simulate_json_and_csv(tmp_path: Path, scenario_file: Callable[..., Path]) -> None:
    scenario = scenario_file(SCENARIO)
    out = tmp_path / "t.csv"
    proc = ergoseek("simulate", str(scenario), "--json", "--csv", str(out))
    assert proc.returncode == 0, proc.stderr
    figures = json.loads(proc.stdout)
    for key in (
        "w_star", "p_star", "wd_final", "power_ratio", "t_1pct", "t_99", "evaluations",
        "passivity_min", "e_rms", "max_abs_u", "sim_seconds", "wall_seconds", "regret",
        "at_bound", "target_min", "target_max", "t_converged", "wd_converged", "optimum_w",
        "optimum_t",
    ):  # fmt: skip
        assert key in figures
    assert figures["w_star"] == pytest.approx(3.0)
    assert figures["sim_seconds"] == 12.0
    assert 1.0 <= figures["target_min"] <= figures["target_max"] <= 4.0
    assert 0.0 <= figures["regret"] < 1.0 and figures["at_bound"] is None
    lines = out.read_text().splitlines()
    assert lines[0] == csv_header()
    assert len(lines) == 1 + 12 * 500


@pytest.mark.parametrize(
    ("text", "key"),
    [
        ("duration = -5.0", "duration"),
        ("[controller]\nks = nan", "controller.ks"),
        ("[user]\nkind = 'robot'", "user.kind"),
        ("[seeker]\nbracket = [3.0, 2.0, 4.0]", "seeker.bracket"),
        ("[seeker]\nbracket = [1.0, 2.0, 40.0]", "seeker.bracket"),
        ("[seeker]\nbrakcet = [1.0, 2.0, 4.0]", "seeker.brakcet"),
        ("rate = 'fast'", "rate"),
        ("[machine\ninertia = 1", "not valid TOML"),
        ("[user]\ntau0 = 1e308", "user.tau0"),
        ("[user]\nkind = 'table'\npoints = [[0.0, 3.0], [1.0, 1.0]]", "user.points"),
        ("[seeker]\nexpand = true", "seeker.expand_limit"),
    ],
)
def test_bad_scenarios_exit_2_naming_the_key(
    scenario_file: Callable[..., Path], text: str, key: str
) -> None:
    scenario = scenario_file(text, "bad.toml")
    proc = ergoseek("simulate", str(scenario))
    assert proc.returncode == 2
    assert key in proc.stderr
    assert "Traceback" not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1
    assert proc.stdout == ""


def test_missing_scenario_is_a_one_line_error(tmp_path: Path) -> None:
    proc = ergoseek("simulate", str(tmp_path / "nope.toml"))
    assert proc.returncode == 2 and "no such file" in proc.stderr and "Traceback" not in proc.stderr


def test_reproduce_writes_figures_summary_and_csv(tmp_path: Path) -> None:
    proc = ergoseek("reproduce", "exp1", "--out", str(tmp_path), "--duration", "20")
    assert proc.returncode == 0, proc.stderr
    for suffix in (".json", ".csv", "-velocity.png", "-torque.png", "-search.png"):
        path = tmp_path / f"exp1{suffix}"
        assert path.exists() and path.stat().st_size > 0
    assert (tmp_path / "exp1-velocity.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    summary = json.loads((tmp_path / "exp1.json").read_text())
    assert summary["config"]["controller"]["ks"] == 1.0  # the paper's gains
    assert summary["w_star"] == pytest.approx(3.0)


PROTOCOL = """
rate = 500.0
seed = 3
[user]
kind = "linear"
tau0 = 2.0
wmax = 6.0
[seeker]
kind = "parabolic"
bracket = [1.0, 2.5, 4.0]
objective = "surrogate"
[[protocol.phases]]
kind = "warmup"
duration = 4.0
velocity = 2.0
[[protocol.phases]]
kind = "train"
intervals = 1
work = 4.0
rest = 3.0
countdown = 1.0
velocity = 3.0
[[protocol.phases]]
kind = "cooldown"
duration = 3.0
"""


def test_simulate_reports_each_protocol_phase(scenario_file: Callable[..., Path]) -> None:
    proc = ergoseek("simulate", str(scenario_file(PROTOCOL)), "--json")
    assert proc.returncode == 0, proc.stderr
    phases = json.loads(proc.stdout)["phases"]
    assert [p["kind"] for p in phases] == ["warmup", "train", "cooldown"]
    assert [p["start"] for p in phases] == pytest.approx([0.0, 4.0, 12.0])  # 4 s; 1 + 4 + 3 s
    for before, after in itertools.pairwise(phases):
        assert before["end"] == pytest.approx(after["start"])
    warm = phases[0]  # a linear user at 2 rad/s: τ = 2 (1 − 2/6), P = 4/3 W once there
    assert warm["peak_power"] == pytest.approx(4.0 / 3.0, rel=0.05)
    assert all(p["work"] >= 0.0 and p["mean_power"] <= p["peak_power"] for p in phases)
    text = ergoseek("simulate", str(scenario_file(PROTOCOL, "p.toml"))).stdout
    assert "phase      train 2" in text
