"""Entry point of the fake UR controller's child process: ``python -m payload_agent.fakes.ur.child FD``.

FD is the child's end of the socket pair ``FakeURController.start()`` created.
"""

import sys
from multiprocessing.connection import Connection

from payload_agent.fakes.ur.process import child_main

if __name__ == "__main__":
    if len(sys.argv) != 2 or not sys.argv[1].isdigit():
        sys.exit("usage: python -m payload_agent.fakes.ur.child FD (started by FakeURController)")
    child_main(Connection(int(sys.argv[1])))
