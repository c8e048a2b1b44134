"""The lazy -> eager switch rule and the eager MILP's invariant rows."""

from __future__ import annotations

import numpy as np

import idstlpy as stl
from idstlpy.backends import HighsBackend, LinearModel
from idstlpy.scenarios import reach_avoid
from idstlpy.synthesis.milp import switch_to_eager


def test_switch_follows_conflict_sizes():
    small = [[1, 2]] * 30
    large = [[1, 2, 3, 4, 5]] * 30
    assert not switch_to_eager(small, 9, 10, 3.0)  # never before lazy_candidates
    assert not switch_to_eager(small[:10], 10, 10, 3.0)  # converging: small conflicts
    assert switch_to_eager(large[:10], 10, 10, 3.0)  # large conflicts: enumerating
    assert switch_to_eager(small + large[:10], 40, 10, 3.0)  # the recent window decides
    assert switch_to_eager(small * 4, 100, 10, 3.0)  # hard cap at 10x
    assert switch_to_eager(small, 10, 10, 0.0)  # 0: the fixed count
    assert switch_to_eager([], 0, 0, 3.0)  # lazy_candidates = 0: eager at once


def test_switch_early_look_reads_the_first_conflicts():
    # Large from the start (PrSTL's noisy reach-avoid, NarrowPassage): eager after 3 candidates.
    assert not switch_to_eager([[0] * 9, [0] * 8], 2, 10, 3.0)  # not before 3 candidates
    assert switch_to_eager([[0] * 9, [0] * 8, [0] * 7], 3, 10, 3.0)
    assert switch_to_eager([[0] * 7, [0] * 5, [0] * 3], 3, 10, 3.0)  # median 5 > 3 + 1
    # The one-obstacle double integrator's 5, 4, 3 (median 4) then 2s: it stays lazy.
    di = [[0] * 5, [0] * 4, [0] * 3] + [[0] * 2] * 9
    assert not any(switch_to_eager(di[:k], k, 10, 3.0) for k in range(3, 13))
    # ReachAvoid's 2s, then conflicts growing at the obstacle: once the last three (guided, from
    # 6 candidates on) have a median above 3, at candidate 9.
    ra = [[0] * n for n in (2, 2, 2, 2, 2, 2, 3, 4, 4, 4, 3, 6, 7)]
    assert [k for k in range(3, 10) if switch_to_eager(ra[:k], k, 10, 3.0)] == [9]
    # The margin holds for the first 2 * 3 candidates only: 4, 4, 4 stays lazy at 5, not at 6.
    fours = [[0] * 4] * 6
    assert not switch_to_eager(fours[:5], 5, 10, 3.0)
    assert switch_to_eager(fours, 6, 10, 3.0)
    # The fixed count has no early look; the early look never goes past lazy_candidates.
    assert not switch_to_eager([[0] * 9] * 3, 3, 10, 0.0)
    assert switch_to_eager([[0] * 9] * 2, 2, 2, 3.0)


def test_one_obstacle_reach_avoid_stays_lazy_and_is_verified():
    problem = reach_avoid(40)
    result = problem.solve_result(seed=0, time_limit=60)
    assert result.status == "found"
    assert result.stats.milp_calls == 0 and "plan LP" in result.reason
    assert stl.satisfies(result.trajectory, problem.stl_formula)
    fixed = problem.solve_result(seed=0, time_limit=60, lazy_conflict_size=0)
    assert fixed.status == "found" and fixed.stats.milp_calls == 1 and fixed.stats.candidates == 10
    assert stl.satisfies(fixed.trajectory, problem.stl_formula)


def test_highs_direct_path_matches_linprog_fallback():
    from scipy.sparse import csr_matrix

    rng = np.random.default_rng(0)
    A = rng.normal(size=(6, 4))
    model = LinearModel(
        rng.normal(size=4), csr_matrix(A), np.full(6, -np.inf), np.ones(6), -np.ones(4), np.ones(4)
    )
    direct = HighsBackend().solve(model, 10)
    fallback = HighsBackend._lp(model, 10)
    assert direct.status == fallback.status == "optimal"
    assert direct.objective == fallback.objective or abs(direct.objective - fallback.objective) < 1e-9
    assert np.allclose(direct.row_duals, fallback.row_duals, atol=1e-9)


def test_exclusion_cliques_keep_the_same_integer_points():
    import itertools

    from idstlpy.synthesis.milp_model import clique_cover, exclusion_cliques

    # Five propositions, all mutually exclusive but 3-4: the cover holds every pair in true cliques.
    edges = frozenset((i, j) for i, j in itertools.combinations(range(5), 2) if (i, j) != (3, 4))
    cover = clique_cover(edges)
    held = {(u, v) for c in cover for u, v in itertools.combinations(sorted(c), 2)}
    assert held == set(edges) and len(cover) < len(edges)
    # As clauses of a 5 x 2 letter grid (variables 1..10): step 1's pairs become cliques, the
    # other clauses (a mixed-step pair, a positive clause) stay, and so does the pair of a
    # sparse step (0), in place.
    p = np.arange(1, 11).reshape(5, 2)
    clauses = [[-int(p[i, 1]), -int(p[j, 1])] for i, j in sorted(edges)]
    clauses += [[-int(p[0, 0]), -int(p[1, 1])], [int(p[2, 0]), int(p[3, 0])], [-int(p[0, 0]), -int(p[1, 0])]]
    rest, step1 = exclusion_cliques(clauses, p)
    assert rest == clauses[-3:]
    assert len(step1) == len(cover) and all(v in p[:, 1] for c in step1 for v in c)
    # Every 0/1 assignment of step 1 meets the pairs exactly when it meets the cliques.
    for bits in itertools.product((0, 1), repeat=5):
        x = {int(p[i, 1]): bits[i] for i in range(5)}
        pairs_ok = all(x[-a] + x[-b] <= 1 for a, b in clauses[: len(edges)])
        assert pairs_ok == all(sum(x[v] for v in c) <= 1 for c in step1)
