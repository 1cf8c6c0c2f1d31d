"""Real-time scheduling for the control loop's thread, and for it alone.

On a busy Pi (CPU and disk load together) an ordinary thread, even at nice −5, wakes tens of
milliseconds late, and the SSR edges with it (bench/timing.py). SCHED_FIFO at a low
real-time priority wakes it within a fraction of a millisecond. Linux applies the policy to
the calling thread only, so threads started before (the recorder, the dead-man) stay
ordinary; with SCHED_RESET_ON_FORK, so do threads and processes the loop thread starts
later. The loop never spins (it sleeps to each deadline), and the kernel's real-time
throttling (`kernel.sched_rt_runtime_us`, 95 % by default) leaves every core some time even
if it did.

Raising the priority needs CAP_SYS_NICE or an RLIMIT_RTPRIO of at least LOOP_PRIORITY
(systemd's `LimitRTPRIO=`); without either the loop runs at ordinary priority, and says so.
"""

from __future__ import annotations

import contextlib
import logging
import os
from collections.abc import Iterator

log = logging.getLogger("hermsd")

LOOP_PRIORITY = 10
"""Above every ordinary thread; below the kernel's threaded interrupts (50) and its
watchdog and migration threads (99), so the loop cannot delay the I2C or USB drivers."""


@contextlib.contextmanager
def loop_priority(priority: int = LOOP_PRIORITY) -> Iterator[bool]:
    """SCHED_FIFO at `priority` for the calling thread while inside; yields whether it took.

    One log line says which. The thread's own policy comes back on leaving (with the
    reset-on-fork flag, which only a privileged thread may clear). Not permitted (an
    unprivileged user without RLIMIT_RTPRIO, a seccomp filter, a kernel without real-time
    scheduling): the thread stays as it was.
    """
    before = os.sched_getscheduler(0) | os.SCHED_RESET_ON_FORK, os.sched_getparam(0)
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO | os.SCHED_RESET_ON_FORK, os.sched_param(priority))
    except OSError as error:
        log.warning(
            "real-time scheduling not permitted (%s): the loop runs at ordinary priority, and "
            "SSR edges may be late on a busy machine (LimitRTPRIO=%d in the unit, or "
            "CAP_SYS_NICE, allows it)",
            error.strerror or error,
            priority,
        )
        yield False
        return
    log.info("control loop at real-time priority %d (SCHED_FIFO)", priority)
    try:
        yield True
    finally:
        with contextlib.suppress(OSError):
            os.sched_setscheduler(0, *before)
