"""What the decoder property tests share: running a decoder call with a hang guard."""

import threading

import pytest

HANG_S = 10.0  # far beyond any timeout a decoder uses: only a real hang gets here


def bounded(fn, *args, timeout_s: float = HANG_S):
    """fn(*args) in a helper thread: its result, or its exception re-raised; a hang fails the test."""
    box: dict = {}

    def run():
        try:
            box["value"] = fn(*args)
        except BaseException as exc:  # noqa: BLE001 - handed to the caller
            box["error"] = exc

    th = threading.Thread(target=run, daemon=True)
    th.start()
    th.join(timeout_s)
    if th.is_alive():
        pytest.fail(f"{getattr(fn, '__name__', fn)} did not return within {timeout_s} s: a hang")
    if "error" in box:
        raise box["error"]
    return box["value"]
