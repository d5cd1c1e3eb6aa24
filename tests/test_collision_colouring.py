"""Graph colouring of contacts into conflict-free batches (the solver's vectorization)."""

import numpy as np
import pytest

from cgp_core.solver.colouring import colour_contacts, contact_priorities


def random_contacts(rng, bodies, contacts, fixed_fraction=0.2):
    dynamic = rng.random(bodies + 1) > fixed_fraction
    dynamic[-1] = False  # the ground row
    a = rng.integers(0, bodies + 1, size=contacts)
    b = rng.integers(0, bodies, size=contacts)
    b = np.where(a == b, (b + 1) % bodies, b)
    return a, b, dynamic


def assert_conflict_free(a, b, dynamic, colour, overflow):
    for c in np.unique(colour):
        if c == overflow:
            continue
        sel = colour == c
        ends = np.concatenate((a[sel][dynamic[a[sel]]], b[sel][dynamic[b[sel]]]))
        assert len(ends) == len(np.unique(ends)), f"colour {c} has a dynamic body twice"


@pytest.mark.parametrize("seed", range(5))
def test_no_colour_shares_a_dynamic_body_and_the_count_is_greedy(seed):
    rng = np.random.default_rng(seed)
    a, b, dynamic = random_contacts(rng, 300, 900)
    colour = colour_contacts(a, b, dynamic, contact_priorities(np.arange(900) * 7 + seed), max_colours=64)
    assert colour.max() < 64  # nobody overflowed
    assert_conflict_free(a, b, dynamic, colour, 64)
    # greedy bound: a contact conflicts with at most deg(a) − 1 + deg(b) − 1 others
    deg = np.bincount(np.concatenate((a[dynamic[a]], b[dynamic[b]])), minlength=len(dynamic))
    assert colour.max() + 1 <= 2 * deg.max() - 1


def test_static_ends_do_not_conflict():
    """Twenty bodies all resting on the ground (row 20, not dynamic) and a fixed wall (row 0): one colour."""
    dynamic = np.ones(21, dtype=bool)
    dynamic[[0, 20]] = False
    a = np.concatenate((np.full(19, 20), np.zeros(19, dtype=int)))
    b = np.concatenate((np.arange(1, 20), np.arange(1, 20)))
    colour = colour_contacts(a, b, dynamic, np.arange(38), max_colours=8)
    # each body has two contacts (ground, wall): two colours, every one filled
    assert sorted(np.bincount(colour).tolist()) == [19, 19]


def test_preset_colours_are_kept_and_the_rest_fit_around_them():
    rng = np.random.default_rng(9)
    a, b, dynamic = random_contacts(rng, 50, 120)
    full = colour_contacts(a, b, dynamic, np.arange(120), max_colours=64)
    preset = np.where(rng.random(120) < 0.7, full, -1)  # 70 % persist from "last step"
    again = colour_contacts(a, b, dynamic, np.arange(120)[::-1].copy(), max_colours=64, preset=preset)
    kept = preset >= 0
    np.testing.assert_array_equal(again[kept], full[kept])
    assert_conflict_free(a, b, dynamic, again, 64)


def test_overflow_when_colours_run_out():
    """A body with 6 contacts needs 6 colours; with 4 the remaining 2 overflow (and nothing else does)."""
    dynamic = np.ones(8, dtype=bool)
    a = np.zeros(6, dtype=int)
    b = np.arange(1, 7)
    colour = colour_contacts(a, b, dynamic, np.arange(6), max_colours=4)
    assert sorted(colour.tolist()) == [0, 1, 2, 3, 4, 4]
    assert_conflict_free(a, b, dynamic, colour, 4)


def test_priorities_are_a_permutation_and_a_pure_function_of_the_keys():
    keys = np.array([5, 1_000_003, 17, 2 ** 40 + 3, 0])
    p = contact_priorities(keys)
    assert sorted(p.tolist()) == list(range(5))
    np.testing.assert_array_equal(p, contact_priorities(keys.copy()))
    with pytest.raises(ValueError, match="max_colours"):
        colour_contacts(np.zeros(1, int), np.ones(1, int), np.ones(2, bool), np.zeros(1, int), max_colours=65)
