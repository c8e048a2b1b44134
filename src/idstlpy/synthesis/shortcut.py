"""Shortening a plan the belief-space sampler found: sampling plans wander.

Each cut replaces a stretch of the plan by the steering law's direct route and is kept only when
the whole re-rolled plan still satisfies the formula (its covariances change with the route, so a
cut that skips a sensing detour is refused).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..belief import rollout_arrays
from .abstraction import Abstraction
from .plan import evaluate_bool
from .steering import Steering

if TYPE_CHECKING:
    from ..problem import Problem

__all__ = ["shortcut"]


def shortcut(
    problem: Problem,
    abstraction: Abstraction,
    steering: Steering,
    actions: np.ndarray,
    controls: np.ndarray,
    max_checks: int = 24,
) -> tuple[np.ndarray, np.ndarray]:
    """Shorten a found plan greedily (sampling plans wander); every accepted cut is re-checked.

    From step ``i``, try to reach the planned mean of a later step ``j`` directly with the
    steering law in fewer steps; splice the cut in when the whole re-rolled plan still
    satisfies the formula (its covariances change: a cut that skips the sensing detour is
    refused). Deterministic, and bounded by ``max_checks`` full re-checks.
    """
    modes = problem.switched_system.system_modes
    formula = problem.stl_formula
    init = problem.initial_state
    checks = 0
    i = 0
    means, covs = rollout_arrays(modes, init.mean, init.cov, actions, controls)
    truth = abstraction.labels(means, covs, actions, 0)
    while checks < max_checks:
        N = actions.shape[0]
        if i >= N - 2:
            break
        improved = False
        for j in sorted({N, (i + N) // 2 + 1, i + (N - i) // 4 + 2, i + 8, i + 4}, reverse=True):
            if not i + 2 <= j <= N or checks >= max_checks:
                continue
            q = int(actions[i])
            mean, target = means[i], means[j]
            cut_u = []
            for t in range(j - i - 1):
                u = steering.steer(q, mean, target, j - i - 1 - t, gentle=True)
                cut_u.append(u)
                mean = modes[q].A @ mean + modes[q].B @ u
                if np.linalg.norm(mean - target) <= 1e-9 * (1.0 + np.linalg.norm(target)):
                    break
            else:
                continue
            new_actions = np.concatenate([actions[:i], np.full(len(cut_u), q), actions[j:]])
            new_controls = np.vstack([controls[:i], np.array(cut_u), controls[j:]])
            checks += 1
            # The prefix up to step i is unchanged: roll and label only the tail.
            tail_m, tail_c = rollout_arrays(modes, means[i], covs[i], new_actions[i:], new_controls[i:])
            m2 = np.vstack([means[:i], tail_m])
            c2 = np.concatenate([covs[:i], tail_c])
            t2 = np.hstack([truth[:, : i + 1], abstraction.labels(m2, c2, new_actions, i + 1)])
            if evaluate_bool(formula, t2, abstraction.index)[id(formula)][0]:
                actions, controls, means, covs, truth = new_actions, new_controls, m2, c2, t2
                improved = True
                break
        if not improved:
            i += max(1, (actions.shape[0] - i) // 8)
    return actions, controls
