"""framework.threads.Chain: steps one after another in a background thread."""
import threading
import time

import pytest

from framework.threads import Chain


def test_chain_runs_its_steps_in_order_from_the_first_value():
    """Each step gets the previous one's value; the caller goes on while a step runs."""
    with Chain([0], name="test") as chain:
        for k in range(1, 6):
            chain.then(lambda seen, k=k: seen + [k])
        assert chain.result() == [0, 1, 2, 3, 4, 5]


def test_chain_holds_one_step_in_flight():
    """``then`` returns while its step runs, and waits for that step before starting the next."""
    release, running = threading.Event(), []
    with Chain(name="test") as chain:
        chain.then(lambda _: (running.append("first"), release.wait(5), "first done")[-1])
        time.sleep(0.05)
        assert running == ["first"]                       # started; the caller went on
        threading.Timer(0.1, release.set).start()
        start = time.perf_counter()
        chain.then(lambda previous: previous + ", second")
        assert time.perf_counter() - start >= 0.05        # waited for the first step
        assert chain.result() == "first done, second"


def test_chain_errors():
    """A step's error is raised by the call that waits for it: the next ``then`` or ``result``."""
    with Chain(name="test") as chain:
        chain.then(lambda _: 1 / 0)
        with pytest.raises(ZeroDivisionError):
            chain.then(lambda v: v)
    with Chain(name="test") as chain:
        chain.then(lambda _: [][1])
        with pytest.raises(IndexError):
            chain.result()
