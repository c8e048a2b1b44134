"""The monitor of executed runs: did a run keep the formula, and which promises did it break?

For one run (:func:`run_record`) or a batch of runs as arrays (:func:`batch_monitor`), the
formula's robustness on the executed belief and on the true states (the formula's deterministic
reading: zero covariance, :func:`state_trajectory`), and for every atomic proposition and every
predicate (face) of it whether execution broke it at a step where the plan satisfies it (the
plan's *promise*, :func:`promises`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..chance import joint_slack, slack, std_terms
from ..formulas import STLAtomicProposition, STLFormula, STLOr
from ..semantics import atom_margins, formula_margins, robustness
from ..trajectory import ProbabilisticTSTrajectory, RealTrajectory

__all__ = [
    "batch_monitor",
    "disjunction_violations",
    "disjunctions",
    "face_slacks",
    "promises",
    "propositions",
    "run_record",
    "state_trajectory",
    "violations",
]


def state_trajectory(real: RealTrajectory) -> ProbabilisticTSTrajectory:
    """The true states as a zero-covariance belief trajectory (the formula's deterministic reading).

    Parameters
    ----------
    real : RealTrajectory
        ``N`` steps of true states, shape (N+1, n).

    Returns
    -------
    ProbabilisticTSTrajectory
        Means = true states, covariances zero, same modes and inputs.
    """
    states = real.get_state()
    n = states.shape[1]
    return ProbabilisticTSTrajectory(
        states, np.zeros((states.shape[0], n, n)), real.get_action(), real.get_control()
    )


def propositions(formula: STLFormula) -> list[STLAtomicProposition]:
    """The atomic propositions of ``formula`` that can be broken (not the constants)."""
    return [ap for ap in formula.atomic_propositions() if not ap.is_false and not ap.is_true]


def disjunctions(formula: STLFormula) -> list[tuple[str, list[int]]]:
    """The disjunctions of atomic propositions in ``formula`` (``left | right | below | above``):
    each one's name and the indices of its operands in :func:`propositions`.

    An operand of a disjunction may be broken at a step the plan promised it while the
    disjunction holds (another operand took over): the monitor reports the disjunction as one.

    Parameters
    ----------
    formula : STLFormula

    Returns
    -------
    list of (str, list of int)
    """
    props = propositions(formula)
    index = {id(ap): i for i, ap in enumerate(props)}
    out: list[tuple[str, list[int]]] = []
    seen: set[int] = set()

    def walk(node: Any) -> None:
        if isinstance(node, STLOr) and id(node) not in seen:
            seen.add(id(node))
            kids = node.children
            if all(isinstance(c, STLAtomicProposition) and id(c) in index for c in kids):
                members = [index[id(c)] for c in kids]
                name = " | ".join(props[i].name or f"ap{i}" for i in members)
                out.append((name, members))
                return
        for child in getattr(node, "children", ()):
            walk(child)

    walk(formula)
    return out


def _or_flags(formula: STLFormula, margins: list[np.ndarray], promised: list[np.ndarray]) -> np.ndarray:
    """Per disjunction, broken at a step the plan promised it: ``margins[i]`` (L, ...) of
    proposition ``i``, ``promised[i]`` its plan's mask; flags of shape (#disjunctions, ...)."""
    flags = []
    for _, members in disjunctions(formula):
        L = min(min(margins[i].shape[0] for i in members), min(promised[i].shape[0] for i in members))
        held = np.max(np.stack([margins[i][:L] for i in members]), axis=0)  # the best operand
        mask = np.any(np.stack([promised[i][:L] for i in members]), axis=0)
        flags.append(np.any(held[mask] < 0.0, axis=0))
    return np.array(flags, dtype=bool)


def disjunction_violations(
    formula: STLFormula, traj: ProbabilisticTSTrajectory, promised: list[np.ndarray]
) -> list[bool]:
    """Per disjunction (:func:`disjunctions`): broken by ``traj`` (every operand's margin below
    zero) at a step where the plan satisfies it.

    Parameters
    ----------
    formula : STLFormula
    traj : ProbabilisticTSTrajectory
        The executed belief (or the true states as a zero-covariance belief).
    promised : list of ndarray
        :func:`promises` of the plan.

    Returns
    -------
    list of bool
    """
    if not disjunctions(formula):
        return []
    means, covs, actions = traj.get_mean(), traj.get_cov(), traj.get_action()
    margins = [atom_margins(ap, means, covs, actions) for ap in propositions(formula)]
    return [bool(v) for v in _or_flags(formula, margins, promised)]


def face_slacks(ap: STLAtomicProposition, means: np.ndarray, covs: np.ndarray) -> np.ndarray:
    """Slack of every chance predicate of ``ap`` at every step, shape (L, k) (:func:`chance.slack`).

    The faces of a joint chance constraint all get its margin (:func:`chance.joint_slack`): each is
    violated where the joint constraint is, as the monitor judges it.
    """
    cone = ap.cone
    if cone.num_faces == 0:
        return np.zeros((means.shape[0], 0))
    out = slack(cone.H, cone.c, cone.z, means, covs)
    at = ap.num_single
    for joint in ap.joints:
        out[:, at : at + joint.num_faces] = joint_slack(joint.H, joint.c, joint.eps, means, covs)[:, None]
        at += joint.num_faces
    return out


def promises(formula: STLFormula, plan: ProbabilisticTSTrajectory, L: int) -> list[np.ndarray]:
    """Per proposition, the steps (< L) at which the plan satisfies it, as boolean masks."""
    out = []
    for ap in propositions(formula):
        margins = atom_margins(ap, plan.get_mean(), plan.get_cov(), plan.get_action())
        mask = np.zeros(L, dtype=bool)
        upto = min(L, margins.shape[0])
        mask[:upto] = margins[:upto] >= 0.0
        out.append(mask)
    return out


def violations(
    formula: STLFormula, traj: ProbabilisticTSTrajectory, promised: list[np.ndarray]
) -> tuple[list[bool], list[bool]]:
    """Per proposition, then per predicate: broken by ``traj`` at a step ``promised`` by the plan."""
    means, covs, actions = traj.get_mean(), traj.get_cov(), traj.get_action()
    props: list[bool] = []
    preds: list[bool] = []
    for ap, mask in zip(propositions(formula), promised, strict=True):
        margins = atom_margins(ap, means, covs, actions)
        # With re-plans the execution may be longer or shorter than the plan: compare the
        # steps both have (the promise is the original plan's).
        mask = mask[: margins.shape[0]]
        margins = margins[: mask.shape[0]]
        props.append(bool(np.any(margins[mask] < 0.0)))
        faces = face_slacks(ap, means, covs)[: mask.shape[0]]
        preds.extend(bool(np.any(faces[mask, j] < 0.0)) for j in range(faces.shape[1]))
    return props, preds


def run_record(
    formula: STLFormula,
    promised: list[np.ndarray],
    xi_sim: ProbabilisticTSTrajectory,
    xi_real: RealTrajectory,
) -> dict[str, Any]:
    """The monitor's record of one run: margins and broken promises, belief and true state.

    Parameters
    ----------
    formula : STLFormula
        The formula the plan satisfies.
    promised : list of ndarray
        :func:`promises` of the plan.
    xi_sim : ProbabilisticTSTrajectory
        The executed belief.
    xi_real : RealTrajectory
        The true states.

    Returns
    -------
    dict
        ``belief_margin``, ``state_margin`` (robustness), ``belief_props``, ``belief_preds``,
        ``state_props``, ``state_preds`` (:func:`violations`), ``belief_ors``, ``state_ors``
        (:func:`disjunction_violations`).
    """
    state_traj = state_trajectory(xi_real)
    b_props, b_preds = violations(formula, xi_sim, promised)
    s_props, s_preds = violations(formula, state_traj, promised)
    return {
        "belief_margin": robustness(xi_sim, formula),
        "state_margin": robustness(state_traj, formula),
        "belief_props": b_props,
        "belief_preds": b_preds,
        "state_props": s_props,
        "state_preds": s_preds,
        "belief_ors": disjunction_violations(formula, xi_sim, promised),
        "state_ors": disjunction_violations(formula, state_traj, promised),
    }


def batch_monitor(
    formula: STLFormula,
    promised: list[np.ndarray],
    means: np.ndarray,
    covs: np.ndarray | None,
    actions: np.ndarray,
) -> dict[str, np.ndarray]:
    """The monitor over a batch of ``S`` trajectories at once.

    ``means`` (L, S, n); ``covs`` (L, n, n) shared by the runs, (L, S, n, n), or None for the
    true states (the deterministic reading: zero covariance). Returns ``margin`` (S,) (the
    robustness at step 0, :func:`~idstlpy.semantics.formula_margins` over the batch), ``props``
    (S, #propositions), ``preds`` (S, #predicates) and ``ors`` (S, #disjunctions,
    :func:`disjunctions`): broken at a promised step. Each face's
    slack is :func:`~idstlpy.chance.slack` (``-(h' mean + c + z sd)``) over the batch.
    """
    L, S, n = means.shape
    atoms: dict[int, np.ndarray] = {}
    faces_of: dict[int, np.ndarray] = {}
    for ap in formula.atomic_propositions():
        key = id(ap)
        if key in atoms:
            continue
        if ap.is_false:
            atoms[key] = np.full((L, S), -np.inf)
            continue
        out = np.full((L, S), np.inf)
        faces = np.zeros((0, L, S))
        if ap.predicates and getattr(ap, "joints", ()):
            # joint chance constraints: the monitor's own atom_margins over the flattened batch
            # (its mode test made void here, applied below), and every face's slack for the counts
            flat_means = means.reshape(L * S, n)
            if covs is None:
                flat_covs = np.zeros((L * S, n, n))
            elif covs.ndim == 3:
                flat_covs = np.broadcast_to(covs[:, None], (L, S, n, n)).reshape(L * S, n, n)
            else:
                flat_covs = covs.reshape(L * S, n, n)
            any_mode = min(ap.modes) if ap.modes else 0
            out = atom_margins(ap, flat_means, flat_covs, np.full(L * S - 1, any_mode)).reshape(L, S)
            # each face's slack, a joint constraint's faces its margin (as the serial loop counts them)
            faces = np.moveaxis(face_slacks(ap, flat_means, flat_covs).reshape(L, S, -1), 2, 0)
        elif ap.predicates:
            cone = ap.cone
            F = cone.H.shape[0]
            if covs is None:
                std = std_terms(cone.H, cone.z, np.zeros((1, n, n)))[0]  # (F,)
            elif covs.ndim == 3:
                std = std_terms(cone.H, cone.z, covs).T[:, :, None]  # (F, L, 1)
            else:
                std = np.moveaxis(std_terms(cone.H, cone.z, covs.reshape(L * S, n, n)).reshape(L, S, F), 2, 0)
            faces = np.empty((F, L, S))
            for j in range(F):
                face = faces[j]
                np.matmul(means, cone.H[j], out=face)
                face += cone.c[j]
                face += std[j]
                np.negative(face, out=face)
            if F:
                out = faces.min(axis=0)
        if ap.modes is not None and L > 1:
            allowed = np.isin(actions, np.fromiter(ap.modes, dtype=int, count=len(ap.modes)))
            out[1:][~allowed] = -np.inf
        atoms[key] = out
        faces_of[key] = faces
    props = np.zeros((S, len(promised)), dtype=bool)
    preds: list[np.ndarray] = []
    for j, (ap, promise) in enumerate(zip(propositions(formula), promised, strict=True)):
        mask = promise[:L]
        props[:, j] = np.asarray((atoms[id(ap)][mask] < 0.0).any(axis=0))
        preds.append(np.asarray((faces_of[id(ap)][:, mask] < 0.0).any(axis=1)).T)  # (S, F)
    margin = formula_margins(formula, atoms, L)[0] if L else np.full(S, -np.inf)
    ors = _or_flags(formula, [atoms[id(ap)] for ap in propositions(formula)], [p[:L] for p in promised])
    return {
        "margin": np.asarray(margin, dtype=float),
        "ors": ors.T.reshape(S, -1) if ors.size else np.zeros((S, 0), dtype=bool),
        "props": props,
        "preds": np.concatenate(preds, axis=1) if preds else np.zeros((S, 0), dtype=bool),
    }
