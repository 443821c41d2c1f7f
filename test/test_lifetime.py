"""Process lifetime helpers (haptic_teleop/lifetime.py) that need no child process."""


def test_a_deadline_fires_while_the_body_runs_and_never_after_it():
    """`lifetime.deadline` (the nodes' bound on a DDS teardown that blocks, and run's notice of a
    long compile): the callback comes while the body still runs; a body that ends first never
    sees it, however long one waits afterwards for the timer's own thread."""
    import threading

    from haptic_teleop.lifetime import deadline

    fired = threading.Event()
    with deadline(0.01, fired.set):
        assert fired.wait(60.0)  # the body waits for it: no timing race

    late = threading.Event()
    with deadline(0.5, late.set):
        pass
    assert not late.wait(1.5)


def test_signals_held_hands_a_signal_inside_the_body_to_its_handler_after_it():
    """A SIGINT inside `signals_held` does not reach its handler while the body runs (a message to
    the bag writer is never cut in half); the handler gets it once the body has ended, and is put
    back. The handler here records instead of raising, so nothing depends on when Python runs it."""
    import os
    import signal
    import time

    from haptic_teleop.lifetime import signals_held

    calls: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: calls.append(signum))
    try:
        mine = signal.getsignal(signal.SIGINT)
        with signals_held():
            os.kill(os.getpid(), signal.SIGINT)
            for _ in range(20):  # Python runs pending handlers between bytecodes and in sleep
                time.sleep(0.001)
            assert calls == []  # held
        assert calls == [signal.SIGINT]  # handed over once the body ended
        assert signal.getsignal(signal.SIGINT) is mine  # put back
        os.kill(os.getpid(), signal.SIGINT)  # outside: straight to the handler
        for _ in range(1000):
            if len(calls) == 2:
                break
            time.sleep(0.001)
        assert calls == [signal.SIGINT, signal.SIGINT]
    finally:
        signal.signal(signal.SIGINT, previous)
