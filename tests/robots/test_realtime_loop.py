"""The fixed-rate loop keeps wall-clock time, counts late ticks and surfaces setup errors."""

import threading
import time

import pytest

from lerobot_actionflow.robots.realtime import FixedRateLoop


def test_ticks_follow_the_wall_clock_and_slow_ticks_count_as_late():
    fast = FixedRateLoop(lambda: None, period=0.02)
    fast.start()
    time.sleep(0.3)
    fast.stop()
    assert 12 <= fast.ticks <= 17, fast.ticks  # 0.3 s / 20 ms = 15, no burst, no drift
    assert fast.late_ticks <= 2

    # Control: a tick slower than the period cannot keep the rate, and says so.
    slow = FixedRateLoop(lambda: time.sleep(0.05), period=0.02)
    slow.start()
    time.sleep(0.3)
    slow.stop()
    assert slow.ticks <= 7 and slow.late_ticks >= 3, (slow.ticks, slow.late_ticks)


def test_setup_and_teardown_run_on_the_loop_thread_and_setup_errors_are_raised():
    threads = {}
    loop = FixedRateLoop(
        lambda: None,
        period=0.01,
        setup=lambda: threads.setdefault("setup", threading.current_thread()),
        teardown=lambda: threads.setdefault("teardown", threading.current_thread()),
    )
    loop.start()
    loop.stop()
    assert threads["setup"] is threads["teardown"] is not threading.current_thread()

    def broken():
        raise OSError("no display")

    with pytest.raises(RuntimeError, match="setup failed: no display"):
        FixedRateLoop(lambda: None, period=0.01, setup=broken).start()
    with pytest.raises(ValueError, match="period"):
        FixedRateLoop(lambda: None, period=0.0)
