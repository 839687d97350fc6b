"""Along the traverse: odometry fused with skyline headings and position fixes (an EKF on x, y,
heading), gated, with an operator request where the skyline cannot help.

``ekf`` the filter; ``inputs`` the traverse folder (``docs/conventions.md``, "Traverse");
``run`` the loop over the stops; ``measure`` the skyline measurements from acquisitions;
``simulate`` a traverse with odometry drift from the simulator.
"""

from .ekf import GATE_CHI2, Odometry, PoseFilter, Update, wrap_deg
from .inputs import Start, Traverse, parse_odometry, read_traverse
from .run import (Measure, Measurement, TraverseConfig, convergence_function, read_done,
                  run_traverse)

__all__ = ["GATE_CHI2", "Measure", "Measurement", "Odometry", "PoseFilter", "Start", "Traverse",
           "TraverseConfig", "Update", "convergence_function", "parse_odometry", "read_done", "read_traverse",
           "run_traverse", "wrap_deg"]
