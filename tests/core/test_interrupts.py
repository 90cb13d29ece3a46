"""interrupts_deferred: a signal inside the block reaches its handler at the block's end."""

from __future__ import annotations

import os
import signal
import threading

import pytest

from iplanner_torch.interrupts import interrupts_deferred


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_inside_the_block_is_handled_once_at_its_end(sig: int) -> None:
    seen: list[tuple[int, str]] = []

    def handler(signum: int, frame: object) -> None:
        seen.append((signum, "handled"))

    previous = signal.signal(sig, handler)
    try:
        with interrupts_deferred():
            os.kill(os.getpid(), sig)
            os.kill(os.getpid(), sig)
            for _ in range(1000):  # bytecodes at which Python would run a handler
                pass
            seen.append((0, "block done"))
        assert seen == [(0, "block done"), (sig, "handled")]
        assert signal.getsignal(sig) is handler  # put back
        os.kill(os.getpid(), sig)  # outside the block: at once
        for _ in range(1000):
            pass
        assert seen[-1] == (sig, "handled") and len(seen) == 3
    finally:
        signal.signal(sig, previous)


def test_a_keyboard_interrupt_comes_after_the_block() -> None:
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    done = []
    try:
        with pytest.raises(KeyboardInterrupt):
            with interrupts_deferred():
                os.kill(os.getpid(), signal.SIGINT)
                for _ in range(1000):
                    pass
                done.append(True)
        assert done == [True]
    finally:
        signal.signal(signal.SIGINT, previous)


def test_off_the_main_thread_it_changes_no_handler() -> None:
    before = signal.getsignal(signal.SIGINT)
    errors: list[BaseException] = []

    def work() -> None:
        try:
            with interrupts_deferred():
                assert signal.getsignal(signal.SIGINT) is before
        except BaseException as err:  # reported in the main thread
            errors.append(err)

    thread = threading.Thread(target=work)
    thread.start()
    thread.join()
    assert errors == []
