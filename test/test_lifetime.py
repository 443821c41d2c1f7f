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
