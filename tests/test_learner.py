import numpy as np

from qpatrol.strategies import learner

INF = -np.inf


def test_greedy_picks_best_legal_and_breaks_ties_by_u():
    q = np.array([[3.0, 2.0, 1.0, 2.0]] * 4)
    legal = np.array([[True, True, True, True], [False, True, True, True]] * 2)
    a, ok = learner.choose(q, legal, np.ones(4), np.array([0.0, 0.0, 0.99, 0.49]), 0.0)
    # row 0/2: North is best; row 1: East/West tie, u=0 -> first (East); row 3: u<0.5 -> East
    assert a.tolist() == [0, 1, 0, 1] and ok.all()
    a, _ = learner.choose(q[1:2], legal[1:2], np.ones(1), np.array([0.5]), 0.0)
    assert a.tolist() == [3]  # u=0.5 of two candidates -> the second, West


def test_no_legal_move():
    a, ok = learner.choose(np.zeros((1, 4)), np.zeros((1, 4), bool), np.ones(1), np.zeros(1), 0.0)
    assert not ok[0]


def test_epsilon_explores_uniformly_over_legal():
    q = np.array([[9.0, 0.0, 0.0, 0.0]])
    legal = np.array([[True, True, False, True]])
    picks = [
        learner.choose(q, legal, np.array([0.1]), np.array([u]), 0.5)[0][0]
        for u in (0.0, 0.34, 0.67)
    ]
    assert picks == [0, 1, 3]
    # u_explore above epsilon: greedy
    assert learner.choose(q, legal, np.array([0.6]), np.array([0.9]), 0.5)[0][0] == 0


def test_update_rule_by_hand():
    target, boot = learner.td_target(
        np.array([2.0]),
        np.array([[5.0, 7.0, 1.0, 100.0]]),
        np.array([[True, True, True, False]]),
        0.5,
    )
    assert boot[0] == 3.5  # the wall move (100) is masked out of the max
    assert target[0] == 5.5
    q, n, alpha = learner.update(np.array([10.0]), np.array([3]), target)
    assert n[0] == 4 and alpha[0] == 0.25
    assert q[0] == 10.0 + 0.25 * (5.5 - 10.0)


def test_pick_takes_the_jth_candidate_for_every_mask():
    """Every candidate mask, uniforms up to the largest below 1 (1 - 2**-53)."""
    import itertools

    masks = np.array(list(itertools.product([False, True], repeat=4)))
    for u in [*np.linspace(0.0, 0.999, 37), np.nextafter(1.0, 0.0)]:
        action, ok = learner.pick(masks, np.full(16, u))
        for row, a, has in zip(masks, action, ok, strict=True):
            cands = np.flatnonzero(row)
            assert has == (cands.size > 0)
            if cands.size:
                assert a == cands[int(u * cands.size)]
