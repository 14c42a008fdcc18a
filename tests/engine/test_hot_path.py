"""The 1 kHz loop imports nothing: a module first loaded mid-session stalls the cycle that
needs it. (numpy 2 loads ``numpy.ma`` lazily; ``np.nanmedian`` touches it, and brent's final
estimate called it on the period it converged: 60-110 ms in one cycle, which on a drive that
keeps turning is a stall past ``catch_up_max``, and the session aborted.)"""

from __future__ import annotations

import json

from testing.processes import python_output

PROBE = """
import json, sys
import sessions.worker.process  # everything a worker imports before its first session
from sessions.config import parse_session_config
from sessions.simulation import run_simulation
run_simulation(parse_session_config({"duration": 0.01}))  # the driver's own first-use imports
before = set(sys.modules)
for kind in ("sweep", "brent", "parabolic", "perturbation", "fixed"):
    # long enough to converge and track
    run_simulation(parse_session_config({"duration": 40.0, "seeker": {"kind": kind}}))
print(json.dumps(sorted(set(sys.modules) - before)))
"""


def test_no_seeker_imports_a_module_during_a_session() -> None:
    assert json.loads(python_output(PROBE, timeout=240)) == []
