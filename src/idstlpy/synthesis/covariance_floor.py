"""A covariance floor over every switching sequence: a sound lower bound for all mode sequences.

The filter covariance of a switched linear system depends on the mode sequence. Where every mode
shares the same state matrix ``A`` a single recursion bounds it from below for *every* sequence:

- **process noise**: a matrix ``W_lo`` with ``W_lo <= W_q W_q'`` (Loewner order) for every mode
  ``q`` (one of the modes' own process covariances when it is below all the others, else
  ``lambda I`` with ``lambda`` the smallest eigenvalue among them);
- **sensor information**: a matrix ``J_hi >= C_q' F_q^{-1} C_q`` for every mode, ``F_q`` the
  mode's noise floor (exact for constant noise, the declared ``V_floor`` for state-dependent
  noise; ``R_q(x) >= F_q`` so the information a measurement brings is at most ``C_q' F_q^{-1}
  C_q``); a blind mode brings none. ``J_hi`` is one of the modes' informations when it is above
  all the others, else ``mu I`` with ``mu`` the largest eigenvalue among them.

The floor map ``g(P) = ((A P A' + W_lo)^{-1} + J_hi)^{-1}`` (covariance form, so a singular
prediction is allowed) is monotone in ``P``, and for every mode ``q`` and every state
``f_q(P) >= g(P)``, where ``f_q`` is the mode's prediction and update (adding less noise and more
information only lowers the posterior; the inverse reverses the order). By induction on ``k``,
from ``L_0 = Sigma_0``: ``Sigma_k = f_{q_k}(Sigma_{k-1}) >= g(Sigma_{k-1}) >= g(L_{k-1}) = L_k``
for every mode sequence ``q_1 .. q_k`` and every mean trajectory.

With different ``A`` matrices no such common bound is claimed (:func:`covariance_floor` returns
``None``); a mode whose sensor floor is singular in an observed direction (a perfect sensor) gives
no finite information bound and no floor either.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, TypeAlias

import numpy as np

from ..dynamical_system import LCS, SwitchedSystem
from .budget import Budget

if TYPE_CHECKING:
    from ..sets import Polytope

Modes: TypeAlias = "Sequence[LCS] | np.ndarray"
"""A system's modes: ``SwitchedSystem.system_modes`` (an object array of LCS) or a list of them."""

__all__ = ["CovarianceFloor", "HullSystem", "covariance_floor", "floor_step", "hull_system"]

_REL = 1e-12


@dataclass(frozen=True)
class CovarianceFloor:
    """The ingredients of the floor map and its schedule.

    Attributes
    ----------
    A : ndarray, shape (n, n)
        The state matrix every mode shares.
    W_lo : ndarray, shape (n, n)
        A common lower bound on the modes' process covariances.
    J_hi : ndarray, shape (n, n)
        A common upper bound on the modes' sensor information ``C' F^{-1} C``.
    covs : ndarray, shape (K + 1, n, n)
        ``L_0 = Sigma_0``, ``L_k = g(L_{k-1})``: below the covariance of every mode sequence.
    how : str
        The argument in words (for proofs' reasons).
    """

    A: np.ndarray
    W_lo: np.ndarray
    J_hi: np.ndarray
    covs: np.ndarray
    how: str


def _min_eig(M: np.ndarray) -> float:
    return float(np.linalg.eigvalsh(0.5 * (M + M.T)).min()) if M.size else 0.0


def _common_lower(mats: Sequence[np.ndarray]) -> tuple[np.ndarray, str]:
    """A matrix below every one of ``mats`` (PSD): one of them when it is, else ``lambda I``."""
    n = mats[0].shape[0]
    scale = 1.0 + max(float(np.abs(M).max()) for M in mats)
    for j, X in enumerate(mats):
        if all(_min_eig(M - X) >= -_REL * scale for M in mats):
            # lowered by the rounding allowance so it is below every one for sure
            return X - _REL * scale * np.eye(n), f"mode {j}'s"
    lam = max(0.0, min(_min_eig(M) for M in mats)) * (1.0 - 1e-9)
    return lam * np.eye(n), f"{lam:.3g} I"


def _common_upper(mats: Sequence[np.ndarray]) -> tuple[np.ndarray, str]:
    """A matrix above every one of ``mats`` (PSD): one of them when it is, else ``mu I``."""
    n = mats[0].shape[0]
    scale = 1.0 + max(float(np.abs(M).max()) for M in mats)
    for j, X in enumerate(mats):
        if all(_min_eig(X - M) >= -_REL * scale for M in mats):
            # lift by the rounding allowance so it is above every one for sure
            return X + _REL * scale * np.eye(n), f"mode {j}'s"
    mu = max(float(np.linalg.eigvalsh(0.5 * (M + M.T)).max()) for M in mats) * (1.0 + 1e-9)
    return mu * np.eye(n), f"{mu:.3g} I"


def _information(mode: LCS) -> np.ndarray | None:
    """``C' F^{-1} C`` with ``F`` the mode's noise floor; zero when blind; ``None`` when unbounded."""
    n = mode.A.shape[0]
    if mode.p == 0:
        return np.zeros((n, n))
    C = np.asarray(mode.C, dtype=float)
    F = np.asarray(mode.noise_floor, dtype=float)
    F = 0.5 * (F + F.T)
    w, v = np.linalg.eigh(F)
    tol = _REL * (1.0 + float(np.abs(F).max()))
    small = w <= tol
    if np.any(small):
        # a direction of the output with no noise floor: unbounded information unless C does not
        # see it (then it carries nothing)
        seen = v[:, small].T @ C
        if np.abs(seen).max() > 0:
            return None
    keep = ~small
    Ck = v[:, keep].T @ C  # (r, n)
    J = Ck.T @ (Ck / w[keep][:, None])
    info: np.ndarray = 0.5 * (J + J.T)
    return info


def floor_step(A: np.ndarray, W_lo: np.ndarray, J_hi: np.ndarray, P: np.ndarray) -> np.ndarray:
    """One step of the floor map ``g(P) = ((A P A' + W_lo)^{-1} + J_hi)^{-1}`` (covariance form).

    Parameters
    ----------
    A, W_lo, J_hi, P : ndarray, shape (n, n)

    Returns
    -------
    ndarray, shape (n, n)
        ``Pm - Pm S (S' Pm S + I)^{-1} S' Pm`` with ``Pm = A P A' + W_lo`` and ``J_hi = S S'``;
        symmetric, negative eigenvalues (rounding) set to zero.
    """
    Pm = A @ P @ A.T + W_lo
    Pm = 0.5 * (Pm + Pm.T)
    w, v = np.linalg.eigh(0.5 * (J_hi + J_hi.T))
    keep = w > 0
    if not np.any(keep):
        out = Pm
    else:
        S = v[:, keep] * np.sqrt(w[keep])[None, :]
        PS = Pm @ S
        M = S.T @ PS + np.eye(S.shape[1])
        out = Pm - PS @ np.linalg.solve(0.5 * (M + M.T), PS.T)
    out = 0.5 * (out + out.T)
    ew, ev = np.linalg.eigh(out)
    return np.asarray((ev * np.maximum(ew, 0.0)) @ ev.T)


def covariance_floor(
    modes: Modes, cov0: np.ndarray, steps: int, budget: Budget | None = None
) -> CovarianceFloor | None:
    """The covariance floor over every switching sequence (see the module docstring).

    Parameters
    ----------
    modes : sequence of LCS
        The switched system's modes.
    cov0 : ndarray, shape (n, n)
        The prior covariance.
    steps : int
        How many steps to roll the floor map (``K``).
    budget : Budget, optional
        Wall-clock cap, checked every 64 steps.

    Returns
    -------
    CovarianceFloor or None
        ``None`` when no sound common bound exists (the modes' ``A`` differ, or a sensor has no
        noise floor in a direction it observes).
    """
    A = np.asarray(modes[0].A, dtype=float)
    scale = 1.0 + float(np.abs(A).max())
    for mode in modes[1:]:
        if np.abs(np.asarray(mode.A, dtype=float) - A).max() > _REL * scale:
            return None
    infos = [_information(mode) for mode in modes]
    if any(J is None for J in infos):
        return None
    W_lo, w_how = _common_lower([np.asarray(mode.process_cov, dtype=float) for mode in modes])
    J_hi, j_how = _common_upper([J for J in infos if J is not None])
    n = cov0.shape[0]
    covs = np.empty((steps + 1, n, n))
    covs[0] = cov0
    for k in range(steps):
        if budget is not None and not (k + 1) % 64:
            budget.check("the covariance floor")
        covs[k + 1] = floor_step(A, W_lo, J_hi, covs[k])
    how = (
        f"every mode shares A; process noise at least {w_how}, sensor information at most {j_how} "
        "(C' F^-1 C with F the noise floor); the Riccati maps are monotone"
    )
    return CovarianceFloor(A, W_lo, J_hi, covs, how)


class HullSystem(SwitchedSystem):
    """One mode whose inputs are every mode's at once: a relaxation of every mode sequence.

    With a common ``A`` and ``0`` in the control domain ``U``, every step of every mode,
    ``A x + B_q u`` with ``u in U``, is a step ``A x + sum_r B_r u_r`` with ``u_r in U`` (take
    ``u_q = u`` and the others zero). With the covariance floor as the covariance schedule
    (every chance constraint only loosens as the covariance shrinks, ``eps <= 0.5``), a plan LP
    on this system that is infeasible proves the requirements infeasible for *every* mode
    sequence.

    A switched system of that one mode (``n`` states, ``M m`` inputs), so the plan LP takes it
    as it takes the problem's.

    Parameters
    ----------
    mode : LCS
        The hull mode (``A``, ``B = [B_0 .. B_{M-1}]``, shape (n, M m); no sensor, no noise: the
        plan LP reads its dynamics only, the covariance floor is its schedule).
    control_domain : Polytope
        ``U^M``, shape (M F, M m).
    """

    def __init__(self, mode: LCS, control_domain: Polytope) -> None:
        super().__init__([mode])
        self.control_domain = control_domain


def hull_system(system: SwitchedSystem, control_domain: Polytope) -> HullSystem | None:
    """The hull relaxation of ``system`` (see :class:`HullSystem`), or ``None`` when it is not
    sound (the modes' ``A`` differ, or ``0`` is outside the control domain).

    Parameters
    ----------
    system : SwitchedSystem
    control_domain : Polytope

    Returns
    -------
    HullSystem or None
    """
    from ..sets import Polytope

    modes = system.system_modes
    A = np.asarray(modes[0].A, dtype=float)
    scale = 1.0 + float(np.abs(A).max())
    if any(np.abs(np.asarray(m.A, dtype=float) - A).max() > _REL * scale for m in modes[1:]):
        return None
    H, c = np.asarray(control_domain.H, dtype=float), np.asarray(control_domain.c, dtype=float)
    if H.shape[0] and float(c.max()) > 0.0:
        return None  # 0 is not an admissible input: the idle modes' inputs cannot be zero
    M, m = len(modes), system.m
    B = np.hstack([np.asarray(mode.B, dtype=float) for mode in modes])
    HH = np.zeros((M * H.shape[0], M * m))
    for q in range(M):
        HH[q * H.shape[0] : (q + 1) * H.shape[0], q * m : (q + 1) * m] = H
    return HullSystem(LCS(A, B), Polytope(HH, np.tile(c, M)))
