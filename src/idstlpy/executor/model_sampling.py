"""Point estimates of an execution's rates by sampling the predicted closed loop.

The Gaussian model (or, under the particle closure or a control domain that is not a box, the
loop itself with the executor's clip or projection, :class:`~idstlpy.loop_samples.LoopStep`) is
sampled; on
every sampled trajectory the chance constraints are judged as ``validate`` judges the executed
belief and the true state, giving the rates it measures (a constraint broken at some promised
step, the formula's success) and a Clopper-Pearson lower bound on the success.
"""

from __future__ import annotations

import numpy as np

from .._deadline import check
from ..chance import joint_tail_sum, std_terms
from ..closed_loop import ClosedLoopMoments, sqrt_psd
from ..formulas import STLAtomicProposition, STLFormula
from ..label_semantics import evaluate_bool
from .success_bound import Faces

__all__ = ["clopper_pearson_lower", "sample_rates"]


def clopper_pearson_lower(rate: float, trials: int, confidence: float = 0.999) -> float:
    """One-sided Clopper-Pearson lower bound of a binomial proportion (NaN without trials)."""
    if not trials or not np.isfinite(rate):
        return float("nan")
    from scipy.stats import beta

    k = int(round(rate * trials))
    return 0.0 if k == 0 else float(beta.ppf(1.0 - confidence, k, trials - k + 1))


def _joint_groups(aps: list[STLAtomicProposition]) -> list[tuple[np.ndarray, float]]:
    """The face rows (in :func:`~idstlpy.executor.success_bound.stack_faces` order) of every
    joint chance constraint, with its ``eps``."""
    out: list[tuple[np.ndarray, float]] = []
    row = 0
    for ap in aps:
        at = row + ap.num_single
        for joint in ap.joints:
            out.append((np.arange(at, at + joint.num_faces), joint.eps))
            at += joint.num_faces
        row += ap.cone.num_faces
    return out


def _sample_events(
    loop: ClosedLoopMoments,
    faces: Faces,
    size: int,
    rng: np.random.Generator,
    roots: list[np.ndarray],
    groups: list[tuple[np.ndarray, float]] | None = None,
) -> dict[str, np.ndarray]:
    """Face truth on ``size`` trajectories sampled from the model, per reading a bool array (S, L, F).

    The faces of a joint chance constraint (``groups``) are judged together, as the monitor and
    ``validate`` do: on the executed belief by Boole's bound (:func:`idstlpy.chance.joint_risk`),
    on the true state as the region; each of them holds in a sample iff the joint constraint does.
    """
    L, D = loop.mean.shape
    nF = faces.H.shape[0]
    ok = {r: np.empty((size, L, nF), dtype=bool) for r in ("state", "belief")}
    const = {r: faces.mu[r] - np.einsum("kfd,kd->kf", faces.a[r], loop.mean) for r in ok}
    z = loop.mean[0] + rng.standard_normal((size, D)) @ roots[0].T
    clipped = loop.closure == "particles" and loop.steps is not None
    # the loop itself: the particles' (the Gauss-Markov model is its regression), or the inputs'
    # projection on a non-box domain, which the Gaussian closure's moments leave out
    through = loop.steps is not None and (clipped or loop.unmodelled_projection)
    for k in range(L):
        check("predicting a plan's execution")  # a solve's time limit (no-op outside a solve)
        if k and through:
            z = loop.steps[k - 1].advance(z, rng)  # type: ignore[index]
        elif k:
            z = z @ loop.F[k - 1].T + loop.g[k - 1] + rng.standard_normal((size, D)) @ roots[k].T
        for r in ok:
            ok[r][:, k] = z @ faces.a[r][k].T + const[r][k] <= 0
        if clipped and loop.sensitivity:  # each sample's own filter covariance, not its linearisation
            n = faces.H.shape[1]
            Pk = loop.P[k] + z[:, 2 * n :].reshape(size, n, n)
            lhs = z[:, n : 2 * n] @ faces.H.T + const["state"][k] + std_terms(faces.H, faces.z, Pk)
            ok["belief"][:, k] = lhs <= 0
        for rows, eps in groups or ():
            n = faces.H.shape[1]
            Hg = faces.H[rows]
            P = loop.P[k] + z[:, 2 * n :].reshape(size, n, n) if loop.sensitivity else loop.P[k]
            d = -(z[:, n : 2 * n] @ Hg.T + const["state"][k][rows])
            sd = np.sqrt(np.maximum(np.einsum("fi,...ij,fj->...f", Hg, P, Hg), 0.0))
            held = joint_tail_sum(d, np.broadcast_to(sd, d.shape)) <= eps
            ok["belief"][:, k, rows] = held[:, None]
            ok["state"][:, k, rows] = np.all(ok["state"][:, k, rows], axis=1)[:, None]  # the region
    return ok


def sample_rates(
    loop: ClosedLoopMoments,
    faces: Faces,
    samples: int,
    seed: int | np.random.SeedSequence | None,
    formula: STLFormula,
    aps: list[STLAtomicProposition],
    mode_ok: np.ndarray,
    plan_truth: np.ndarray,
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], dict[str, float], dict[str, np.ndarray]]:
    """Model-sampled rates, in chunks of bounded memory: per reading, each face broken at some
    promised step (F,), each proposition broken at some promised step (A,), the formula's success,
    and each face's per-step probability of holding (L, F)."""
    rng = np.random.default_rng(seed)
    L = loop.mean.shape[0]
    nF = faces.H.shape[0]
    roots = [sqrt_psd(loop.cov[0])] + [sqrt_psd(Q) for Q in loop.Q]
    promised = plan_truth[faces.atom].T[None]  # (1, L, F)
    readings = ("state", "belief")
    face_n = {r: np.zeros(nF) for r in readings}
    prop_n = {r: np.zeros(len(aps)) for r in readings}
    ok_n = {r: 0.0 for r in readings}
    step_n = {r: np.zeros((L, nF)) for r in readings}
    chunk = max(1, min(samples, 30_000_000 // max(1, L * max(nF, 1))))
    done = 0
    while done < samples:
        size = min(chunk, samples - done)
        ok = _sample_events(loop, faces, size, rng, roots, _joint_groups(aps))
        for r in readings:
            step_n[r] += np.sum(ok[r], axis=0)
            broken = ~ok[r] & promised  # (S, L, F)
            face_n[r] += np.sum(np.any(broken, axis=1), axis=0)
            for i in range(len(aps)):
                prop_n[r][i] += np.sum(np.any(broken[:, :, faces.atom == i], axis=(1, 2)))
            ok_n[r] += _formula_rate(formula, aps, ok[r], faces, mode_ok) * size
        done += size
    return (
        {r: face_n[r] / samples for r in readings},
        {r: prop_n[r] / samples for r in readings},
        {r: ok_n[r] / samples for r in readings},
        {r: step_n[r] / samples for r in readings},
    )


def _formula_rate(
    formula: STLFormula,
    aps: list[STLAtomicProposition],
    face_ok: np.ndarray,
    faces: Faces,
    mode_ok: np.ndarray,
) -> float:
    """Fraction of sampled trajectories (face truth (S, L, F)) on which the formula holds."""
    S, L, _ = face_ok.shape
    truth = np.empty((S, len(aps), L), dtype=bool)
    for i in range(len(aps)):
        truth[:, i] = np.all(face_ok[:, :, faces.atom == i], axis=2) & mode_ok[i][None, :]
    packed = np.packbits(truth.reshape(S, -1), axis=1)
    uniq, inverse = np.unique(packed, axis=0, return_inverse=True)
    atom_index = {id(ap): i for i, ap in enumerate(aps)}
    holds = np.empty(uniq.shape[0], dtype=bool)
    for u in range(uniq.shape[0]):
        row = np.unpackbits(uniq[u], count=len(aps) * L).astype(bool).reshape(len(aps), L)
        holds[u] = bool(evaluate_bool(formula, row, atom_index)[id(formula)][0])
    return float(np.mean(holds[np.asarray(inverse).reshape(-1)]))
