"""Independent ground truth for chance switching (issue 35), written from the definitions only.

- :func:`all_sequences`: every executed mode sequence and its probability, by brute-force
  enumeration (``itertools.product``) of the chain's definition
  (``s_0 ~ initial or P[q_0, q_0]``, ``s_{k+1} ~ P[q_{k+1}, s_k]``).
- :func:`exact_always_probability`: the exact probability that the true states satisfy
  ``h_f' x_k + c_f <= 0`` for every face ``f`` and step ``k`` of ``steps``, summed over EVERY
  executed sequence. Given a sequence the closed loop (tracking ``u = v - K_s (xhat - m)``,
  Kalman filter with the executed mode's model, the executed mode's plant and sensor) is affine
  in one Gaussian vector (start, process and sensor noises), which this module builds by hand;
  the probability of the intersection of half-spaces is the Gaussian CDF of the stacked faces
  (scipy's ``multivariate_normal.cdf``).
- :func:`monte_carlo_always`: the same probability by simulating the loop from scratch (its own
  draws of the chain and the noises), with an optional box clip of the input.

Nothing here calls the package's prediction, executor or bound.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from scipy.stats import multivariate_normal


@dataclass(frozen=True)
class Mode:
    """One mode: ``x' = A x + B u + W w``, ``y = C x' + V v`` (``C`` may have 0 rows)."""

    A: np.ndarray
    B: np.ndarray
    W: np.ndarray
    C: np.ndarray
    V: np.ndarray


def all_sequences(
    P: np.ndarray, commanded: list[int], initial: np.ndarray | None = None
) -> dict[tuple[int, ...], float]:
    """Every executed sequence with positive probability (brute force over M^N)."""
    M = P.shape[1]
    out: dict[tuple[int, ...], float] = {}
    for seq in itertools.product(range(M), repeat=len(commanded)):
        q0 = commanded[0]
        p = (initial if initial is not None else P[q0, q0])[seq[0]]
        for k in range(1, len(seq)):
            p *= P[commanded[k], seq[k - 1], seq[k]]
        if p > 0:
            out[seq] = float(p)
    return out


def _affine_states(
    modes: list[Mode],
    K: list[np.ndarray],
    means: np.ndarray,
    inputs: np.ndarray,
    seq: tuple[int, ...],
    x0: np.ndarray,
    x0_cov: np.ndarray,
    P0: np.ndarray,
) -> tuple[list[np.ndarray], list[np.ndarray], np.ndarray]:
    """x_k = a_k + G_k xi for k = 0..N, xi ~ N(0, I) the stacked start, process and sensor noises."""
    n = x0.shape[0]
    dims = [n] + [modes[s].W.shape[1] + modes[s].V.shape[1] for s in seq]
    D = sum(dims)
    root = np.linalg.cholesky(x0_cov + 1e-300 * np.eye(n)) if np.any(x0_cov) else np.zeros((n, n))
    a_x, G_x = x0.copy(), np.zeros((n, D))
    G_x[:, :n] = root
    a_h, G_h = means[0].copy(), np.zeros((n, D))  # the filter mean starts at the plan's
    P = P0.copy()
    off = n
    xs_a, xs_G = [a_x.copy()], [G_x.copy()]
    for k, s in enumerate(seq):
        md = modes[s]
        r_w, r_v = md.W.shape[1], md.V.shape[1]
        # u = v - K (xhat - m)
        a_u = inputs[k] - K[s] @ (a_h - means[k])
        G_u = -K[s] @ G_h
        a_x = md.A @ a_x + md.B @ a_u
        G_x = md.A @ G_x + md.B @ G_u
        G_x[:, off : off + r_w] += md.W
        a_p = md.A @ a_h + md.B @ a_u
        G_p = md.A @ G_h + md.B @ G_u
        Pp = md.A @ P @ md.A.T + md.W @ md.W.T
        if md.C.shape[0]:
            R = md.V @ md.V.T
            S = md.C @ Pp @ md.C.T + R
            L = Pp @ md.C.T @ np.linalg.inv(S)
            # y = C x' + V v;  xhat' = xpred + L (y - C xpred)
            a_h = a_p + L @ (md.C @ a_x - md.C @ a_p)
            G_h = G_p + L @ (md.C @ G_x - md.C @ G_p)
            G_h[:, off + r_w : off + r_w + r_v] += L @ md.V
            IKC = np.eye(n) - L @ md.C
            P = IKC @ Pp @ IKC.T + L @ R @ L.T
        else:
            a_h, G_h, P = a_p, G_p, Pp
        off += r_w + r_v
        xs_a.append(a_x.copy())
        xs_G.append(G_x.copy())
    return xs_a, xs_G, np.eye(D)


def exact_always_probability(
    modes: list[Mode],
    K: list[np.ndarray],
    means: np.ndarray,
    inputs: np.ndarray,
    P: np.ndarray,
    commanded: list[int],
    x0: np.ndarray,
    x0_cov: np.ndarray,
    P0: np.ndarray,
    H: np.ndarray,
    c: np.ndarray,
    steps: list[int],
    initial: np.ndarray | None = None,
) -> float:
    """P[H x_k + c <= 0 for every k in steps], summed over every executed sequence (module notes)."""
    total = 0.0
    for seq, p in all_sequences(P, commanded, initial).items():
        a, G, _ = _affine_states(modes, K, means, inputs, seq, x0, x0_cov, P0)
        mu = np.concatenate([H @ a[k] + c for k in steps])
        rows = np.vstack([H @ G[k] for k in steps])
        cov = rows @ rows.T
        sd = np.sqrt(np.diag(cov))
        det = sd < 1e-12  # deterministic faces: true or false outright
        if np.any(mu[det] > 0):
            continue
        keep = ~det
        if not keep.any():
            total += p
            continue
        z = -mu[keep] / sd[keep]
        corr = cov[np.ix_(keep, keep)] / np.outer(sd[keep], sd[keep])
        mvn = multivariate_normal(
            mean=np.zeros(z.shape[0]), cov=corr, allow_singular=True,
            maxpts=200000 * z.shape[0], abseps=1e-7, releps=1e-7,
        )  # fmt: skip
        prob = mvn.cdf(z)
        total += p * float(prob)
    return total


def monte_carlo_always(
    modes: list[Mode],
    K: list[np.ndarray],
    means: np.ndarray,
    inputs: np.ndarray,
    P: np.ndarray,
    commanded: list[int],
    x0: np.ndarray,
    x0_cov: np.ndarray,
    P0: np.ndarray,
    H: np.ndarray,
    c: np.ndarray,
    steps: list[int],
    runs: int,
    seed: int,
    box: tuple[np.ndarray, np.ndarray] | None = None,
    initial: np.ndarray | None = None,
    observed: bool = True,
) -> float:
    """The fraction of ``runs`` simulated executions whose true states satisfy every face at every step.

    ``observed=False``: the tracking gain and the filter are the commanded mode's, the plant and
    the sensor the executed mode's (every mode must then have the same output dimension).
    """
    rng = np.random.default_rng(seed)
    n = x0.shape[0]
    ok = 0
    for _ in range(runs):
        x = rng.multivariate_normal(x0, x0_cov) if np.any(x0_cov) else x0.copy()
        xh, Pk = means[0].copy(), P0.copy()
        q0 = commanded[0]
        law = initial if initial is not None else P[q0, q0]
        s = int(rng.choice(len(law), p=law))
        good = bool(np.all(H @ x + c <= 0)) if 0 in steps else True
        for k in range(len(commanded)):
            if k > 0:
                s = int(rng.choice(P.shape[1], p=P[commanded[k], s]))
            md = modes[s]  # the plant and the sensor
            b = md if observed else modes[commanded[k]]  # what the executor believes
            u = inputs[k] - K[s if observed else commanded[k]] @ (xh - means[k])
            if box is not None:
                u = np.clip(u, box[0], box[1])
            x = md.A @ x + md.B @ u + md.W @ rng.standard_normal(md.W.shape[1])
            xp = b.A @ xh + b.B @ u
            Pp = b.A @ Pk @ b.A.T + b.W @ b.W.T
            if md.C.shape[0]:
                y = md.C @ x + md.V @ rng.standard_normal(md.V.shape[1])
                R = b.V @ b.V.T
                L = Pp @ b.C.T @ np.linalg.inv(b.C @ Pp @ b.C.T + R)
                xh = xp + L @ (y - b.C @ xp)
                IKC = np.eye(n) - L @ b.C
                Pk = IKC @ Pp @ IKC.T + L @ R @ L.T
            else:
                xh, Pk = xp, Pp
            if k + 1 in steps and not np.all(H @ x + c <= 0):
                good = False
        ok += good
    return ok / runs
