"""Worker process that holds ur-rtde's RTDEControlInterface for the UR driver (see ``control.py``).

Run as a script (``python control_worker.py FD``; no package imports, so it starts in ~0.1 s).
It answers one request at a time on the socket FD: ``(op, *args)`` -> ``("ok", result, status)``
or ``("error", exception type, text, status)``, status = (isConnected, isProgramRunning).
It exits when the driver closes the socket, and the driver kills it when a call hangs.
"""

import sys
from multiprocessing.connection import Connection

CALLS = {"moveJ", "stopJ", "setPayload", "setTargetPayload", "getTCPOffset", "stopScript", "reuploadScript", "isSteady"}


def _status(ctrl):
    if ctrl is None:
        return (False, False)
    try:
        connected = bool(ctrl.isConnected())
        return (connected, connected and bool(ctrl.isProgramRunning()))
    except Exception:  # noqa: BLE001 - a broken interface is simply not connected
        return (False, False)


def main(fd: int) -> None:
    conn = Connection(fd)
    import rtde_control

    ctrl = None
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            break
        op, args = msg[0], msg[1:]
        try:
            if op == "open":
                host, frequency_hz, flags = args
                ctrl = rtde_control.RTDEControlInterface(host, frequency_hz, flags)
                result = None
            elif op == "close":
                if ctrl is not None:
                    ctrl.disconnect()
                conn.send(("ok", None, (False, False)))
                break
            elif ctrl is None:
                raise RuntimeError("no control interface (open first)")
            elif op == "progress":
                st = ctrl.getAsyncOperationProgressEx()
                result = (st.operationId(), bool(st.isAsyncOperationRunning()))
            elif op == "status":
                result = None
            elif op in CALLS:
                result = getattr(ctrl, op)(*args)
            else:
                raise ValueError(f"unknown request {op!r}")
            conn.send(("ok", result, _status(ctrl)))
        except Exception as exc:  # noqa: BLE001 - reported to the driver
            conn.send(("error", type(exc).__name__, str(exc), _status(ctrl)))


if __name__ == "__main__":
    main(int(sys.argv[1]))
