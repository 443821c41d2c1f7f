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
    """A SIGINT inside `signals_held` does not interrupt the body (a message to the bag writer is
    never cut in half); the KeyboardInterrupt comes once the body has ended. Outside, at once."""
    import os
    import signal

    import pytest

    from haptic_teleop.lifetime import signals_held

    done = []
    with pytest.raises(KeyboardInterrupt):
        with signals_held():
            os.kill(os.getpid(), signal.SIGINT)
            for _ in range(1000):  # the handler would run between these bytecodes
                done.append(1)
    assert len(done) == 1000
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # put back
    with pytest.raises(KeyboardInterrupt):
        os.kill(os.getpid(), signal.SIGINT)
        for _ in range(1000):
            done.append(2)
    assert done.count(2) < 1000
