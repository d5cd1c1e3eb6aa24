"""Issue 37: the convex phase split in two calls at once, the second on the machine's second core
(cgp_core.second_core, CollisionDetector._convex_contacts) — the same contacts bit for bit as one call, so the
same simulation: the gallery's convex pile (hulls and rocks on a terrain mesh: hull pairs, mesh pairs with their
BVH scratch, the ground) stepped with the split forced and with it off; and
second_core's own contract (its result and errors handed back, on the calling thread when it is off, in a forked
child)."""

from __future__ import annotations

import multiprocessing
import threading

import numba
import numpy as np
import pytest

from cgp_core import World, second_core
from cgp_core.collision import detector

TWO_THREADS = pytest.mark.skipif(not second_core.available(), reason="needs numba's JIT and a pool of 2 threads")


def run(scene: str, ticks: int, split: bool, monkeypatch) -> tuple[np.ndarray, int]:
    """The bodies' state after each of ``ticks`` ticks of ``scene``, the split forced (from 1 pair on) or off; and
    how many calls went to the second thread."""
    calls = []
    beside = second_core.beside

    def counted(function, *args):
        calls.append(function)
        return beside(function, *args)

    with monkeypatch.context() as patch:
        limit = 1 if split else 10**9
        patch.setattr(detector, "CONVEX_SPLIT_MIN_PAIRS", limit)
        patch.setattr(second_core, "beside", counted)
        world = World.from_scene(scene)
        out = []
        for _ in range(ticks):
            world.step()
            s = world.body_state
            out.append(np.concatenate((s.position, s.orientation, s.linear_momentum, s.angular_momentum), axis=1))
    return np.array(out), len(calls)


@TWO_THREADS
def test_the_split_convex_phase_steps_to_the_same_bits_as_one_call(monkeypatch):
    whole, none = run("convex_pile", 90, False, monkeypatch)
    split, calls = run("convex_pile", 90, True, monkeypatch)
    assert none == 0 and calls >= 90  # (every sub-step with pairs split)
    assert np.abs(whole[-1, :, 2] - whole[0, :, 2]).max() > 0.05  # the bodies fell
    np.testing.assert_array_equal(whole, split)


@TWO_THREADS
def test_the_split_contacts_are_one_calls_in_its_order(monkeypatch):
    """One sub-step's contact set of the convex pile in mid-fall, field by field, whatever the cut."""
    world = World.from_scene("convex_pile")
    for _ in range(60):
        world.step()
    model, state = world.body_model, world.body_state
    h = world.dt / world.substeps
    monkeypatch.setattr(detector, "CONVEX_SPLIT_MIN_PAIRS", 10**9)
    one = world.solver.detector.detect(model, state, h, ground=world.ground)
    monkeypatch.setattr(detector, "CONVEX_SPLIT_MIN_PAIRS", 1)
    for weight in (0.0, 0.2, 5.0, 1e6):  # the cut from the middle of the pairs to all of them in the first call
        monkeypatch.setattr(detector, "GROUND_PER_PAIR", weight)
        two = world.solver.detector.detect(model, state, h, ground=world.ground)
        assert one.count > 20
        for name, a, b in zip(one._fields, one, two):
            np.testing.assert_array_equal(a, b, err_msg=name)


def test_beside_hands_back_the_result_and_the_error():
    assert second_core.beside(np.add, 2, 3).result() == 5
    with pytest.raises(ZeroDivisionError):
        second_core.beside(lambda: 1 / 0).result()


@TWO_THREADS
def test_beside_runs_on_another_thread_and_on_the_calling_one_with_a_pool_of_one(monkeypatch):
    here = threading.get_ident()
    assert second_core.beside(threading.get_ident).result() != here
    monkeypatch.setattr(numba.config, "NUMBA_NUM_THREADS", 1)
    assert not second_core.available()
    assert second_core.beside(threading.get_ident).result() == here


def _in_child(queue) -> None:
    queue.put(second_core.beside(threading.get_ident).result() != threading.get_ident())


@TWO_THREADS
def test_a_forked_child_gets_a_thread_of_its_own():
    """The parent's thread is not in a forked child: a call there must not wait for it forever."""
    second_core.beside(len, ()).result()  # the parent's thread is started
    context = multiprocessing.get_context("fork")
    queue = context.Queue()
    child = context.Process(target=_in_child, args=(queue,))
    child.start()
    child.join(60)
    assert child.exitcode == 0
    assert queue.get(timeout=5) is True
