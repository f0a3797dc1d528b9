"""The simulated UR e-Series controller: kept importable here; it lives in ``payload_agent.fakes.ur``.

``python -m payload_agent.fakes.ur_controller [HOST]`` serves one in this process until Ctrl-C
(for poking at it with a raw socket or another process's ur_rtde client).
"""

from payload_agent.fakes.ur import (DEFAULT_GAINS_NM_PER_A, DEFAULT_TCP_OFFSET, FakeURController, URControllerCore,
                                    pick_loopback_host)

__all__ = ["FakeURController", "URControllerCore", "DEFAULT_GAINS_NM_PER_A", "DEFAULT_TCP_OFFSET",
           "pick_loopback_host"]

if __name__ == "__main__":
    import sys
    import time

    with FakeURController(sys.argv[1] if len(sys.argv) > 1 else None, in_process=True) as _ur:
        print(f"fake UR controller on {_ur.host} (Ctrl-C to stop)")
        try:
            while True:
                time.sleep(1)
        except KeyboardInterrupt:
            pass
