"""A question at the terminal gives way to a signal whichever thread the kernel delivered it to."""

import os
import signal
import threading
import time

import pytest

from payload_agent.output.line_input import read_line


class _Signalled(Exception):
    pass


def _raise(signum, frame):
    raise _Signalled()


def test_a_signal_delivered_to_another_thread_interrupts_the_question():
    r, w = os.pipe()
    previous = signal.signal(signal.SIGUSR1, _raise)
    delivered = threading.Event()

    def other_thread():
        reading.wait(30)
        time.sleep(0.3)  # main is inside read_line by now (on a slow host the handler may run before; never a false failure)
        signal.pthread_kill(threading.get_ident(), signal.SIGUSR1)  # the handler's C part runs here, not in main
        delivered.set()
        if not done.wait(30):  # unblock a reader that never saw the signal, so the test fails instead of hanging
            forced.set()
            os.write(w, b"never interrupted\n")

    done, reading, forced = threading.Event(), threading.Event(), threading.Event()
    try:
        with open(r, "r", encoding="utf-8", closefd=False) as stream:
            t = threading.Thread(target=other_thread, daemon=True)
            t.start()
            with pytest.raises(_Signalled):
                reading.set()
                read_line(stream)
            assert delivered.is_set()
            assert not forced.is_set(), "the handler ran only after a line came: the signal did not interrupt the question"
    finally:
        done.set()
        signal.signal(signal.SIGUSR1, previous)
        os.close(r)
        os.close(w)


def test_lines_come_one_at_a_time_with_nothing_held_back():
    r, w = os.pipe()
    try:
        os.write(w, "ja\nnein\nüber".encode())
        os.close(w)
        w = -1
        with open(r, "r", encoding="utf-8", closefd=False) as stream:
            assert read_line(stream) == "ja\n"
            assert read_line(stream) == "nein\n"
            assert read_line(stream) == "über"
            assert read_line(stream) == ""
    finally:
        os.close(r)
        if w >= 0:
            os.close(w)


def test_an_in_memory_stream_is_read_as_it_is():
    import io

    assert read_line(io.StringIO("y\nn\n")) == "y\n"
