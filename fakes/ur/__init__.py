"""The simulated Universal Robots e-Series controller, one module per job.

- ``process``: ``FakeURController``, the simulated-controller contract, hosted in a child process;
- ``controller``: ``URControllerCore``, the controller state and control cycle;
- ``rtde_session``: one RTDE client (port 30004); ``outputs``: what each RTDE output field reads;
- ``dashboard``: the dashboard server (29999);
- ``programs``: the script ports (30001-30003) and the running program; ``urscript``: the URScript
  subset; ``control_script``: ur_rtde's control script, emulated;
- ``faults``: the injectable faults; ``constants``: ports, codes and defaults.
"""

from payload_agent.fakes.ur.constants import DEFAULT_GAINS_NM_PER_A, DEFAULT_TCP_OFFSET, pick_loopback_host
from payload_agent.fakes.ur.controller import URControllerCore
from payload_agent.fakes.ur.process import FakeURController

__all__ = ["FakeURController", "URControllerCore", "DEFAULT_GAINS_NM_PER_A", "DEFAULT_TCP_OFFSET",
           "pick_loopback_host"]
