"""The proposition abstraction: letters, their regions, and sound LP pruning.

Every pruning fact is proved on the *mean-only relaxation*: a belief can satisfy a chance
constraint only if its mean satisfies the deterministic constraint (the covariance term is
non-negative), so a step that no mean can make is impossible for every belief.

A joint chance constraint ``prob_in(region) >= 1 - eps`` is read here as the monitor reads it
(:func:`idstlpy.chance.joint_tail_sum`: Boole's bound with the best per-face allocation at that
step), not at the shares the plan LP plans with: a belief the monitor accepts is labelled true
(the prior at step 0, the sampler's and the LP's beliefs), and a belief labelled false is false
for every allocation, so the step-0 claim is a proof. The covariance-floor claim
(:meth:`Abstraction.out_of_reach`) reads each of its faces alone at ``eps`` (necessary).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from scipy.sparse import coo_matrix, csr_matrix, diags, vstack

from ..backends import Backend, HighsBackend, LinearModel
from ..chance import joint_tail_sum, quantile, std_terms
from ..expressions import JointFace
from ..formulas import STLAtomicProposition, STLFormula
from ..sets import Polytope
from .budget import Budget
from .proofs import AllOf, FaceProof, ModelProof, NoProof, Proof

if TYPE_CHECKING:
    from ..dynamical_system import SwitchedSystem

__all__ = ["Abstraction", "PruningReport"]

logger = logging.getLogger(__name__)


@dataclass
class PruningReport:
    """What LP pruning proved.

    Attributes
    ----------
    empty_atoms : list of int
        Propositions whose region is empty (they can never hold).
    disjoint_pairs : list of (int, int)
        Propositions that can never hold together.
    impossible_steps : list of (int, int, int)
        ``(i, j, q)``: no mean in region ``i`` reaches region ``j`` in one step of mode ``q``
        (``q = -1``: of any mode).
    initial_false : list of int
        Propositions the initial belief does not satisfy.
    out_of_reach : dict of int to str
        Propositions no belief can satisfy at any step ``>= 1`` (their confidence needs less
        covariance than a sound lower bound allows), with the proof in words.
    impossible_gaps : list of (int, int, int)
        ``(i, j, d)`` with ``d >= 2``: no mean in region ``i`` reaches region ``j`` in exactly
        ``d`` steps, whatever the modes (``Abstraction.prune(..., reach=True)``).
    roomless_gaps : list of (int, int, int)
        ``(i, j, d)``: region ``i``'s centre cannot reach region ``j``'s in ``d`` steps (but
        some mean in ``i`` reaches ``j``): a transition with no room for the execution. Not a
        proof; the proposer only prefers plans without such transitions.
    proofs : dict
        What proves each fact, by key ``("empty", i)``, ``("disjoint", i, j)``,
        ``("step", i, j, q)``, ``("gap", i, j, d)``, ``("initial", i)``, ``("reach", i)``
        (:mod:`.proofs`; read only for the certificate of an ``infeasible``).
    """

    empty_atoms: list[int]
    disjoint_pairs: list[tuple[int, int]]
    impossible_steps: list[tuple[int, int, int]]
    initial_false: list[int]
    out_of_reach: dict[int, str] = field(default_factory=dict)
    impossible_gaps: list[tuple[int, int, int]] = field(default_factory=list)
    roomless_gaps: list[tuple[int, int, int]] = field(default_factory=list)
    proofs: dict[tuple[object, ...], Proof] = field(default_factory=dict, repr=False)


class Abstraction:
    """Non-constant atomic propositions of a formula, with vectorised evaluation.

    Parameters
    ----------
    formula : STLFormula
    n : int
        State dimension.
    """

    def __init__(self, formula: STLFormula, n: int) -> None:
        # TRUE / FALSE are constants in the encoding, not letters.
        self.atoms: list[STLAtomicProposition] = [
            ap for ap in formula.atomic_propositions() if ap._constant is None
        ]
        self.index = {id(a): i for i, a in enumerate(self.atoms)}
        self.n = n
        H, c, z, owner = [], [], [], []
        # Joint constraints' faces: (atom, rows into H, eps), judged together (Boole's bound).
        self.joint_groups: list[tuple[int, np.ndarray, float]] = []
        row = 0
        for i, ap in enumerate(self.atoms):
            if ap.predicates:
                cone = ap.cone
                H.append(cone.H)
                c.append(cone.c)
                z.append(cone.z)
                owner.extend([i] * cone.num_faces)
                at = row + ap.num_single
                for joint in ap.joints:
                    self.joint_groups.append((i, np.arange(at, at + joint.num_faces), joint.eps))
                    at += joint.num_faces
                row += cone.num_faces
        self.H = np.vstack(H) if H else np.zeros((0, n))
        self.c = np.concatenate(c) if c else np.zeros(0)
        self.z = np.concatenate(z) if z else np.zeros(0)
        self.owner = np.asarray(owner, dtype=int)
        self.joint_rows = np.zeros(self.H.shape[0], dtype=bool)
        for _, rows, _ in self.joint_groups:
            self.joint_rows[rows] = True
        self.num_atoms = len(self.atoms)
        self.mode_sets = [ap.modes for ap in self.atoms]
        # What proves each proposition out of reach (:meth:`out_of_reach`), for certificates: by
        # proposition, or by (proposition, step) where each step has its own.
        self.reach_proofs: dict[int | tuple[int, int], Proof] = {}

    def names(self) -> list[str]:
        """Readable names of the propositions."""
        return [ap.name or f"ap{i}" for i, ap in enumerate(self.atoms)]

    def face_slack(self, mean: np.ndarray, cov: np.ndarray) -> np.ndarray:
        """Slack of every face (>= 0 satisfied), shape (F,)."""
        if not self.H.shape[0]:
            return np.zeros(0)
        if not cov.any():
            # Zero covariance (STL, and every noise-free plan): every standard-deviation term is 0.
            zero: np.ndarray = -(mean @ self.H.T + self.c)
            return zero
        # The lazy loop labels the same covariance schedule candidate after candidate: the
        # standard-deviation terms depend on the covariance alone, so they are kept by its bytes.
        cache: dict[tuple[tuple[int, ...], bytes], np.ndarray] = self.__dict__.setdefault("_std_terms", {})
        key = (cov.shape, cov.tobytes())
        terms = cache.get(key)
        if terms is None:
            if len(cache) >= 1 << 14:
                cache.clear()
            terms = cache[key] = std_terms(self.H, self.z, cov)
        slack: np.ndarray = -(mean @ self.H.T + self.c + terms)
        return slack

    def truth(self, mean: np.ndarray, cov: np.ndarray, arrival_mode: int) -> np.ndarray:
        """Which propositions hold for belief ``N(mean, cov)`` reached with ``arrival_mode``.

        ``arrival_mode < 0`` means step 0 (mode atoms are vacuous).
        """
        out = self._mode_truth(arrival_mode).copy()
        if self.H.shape[0]:
            bad = (self.face_slack(mean, cov) < 0) & ~self.joint_rows
            out[self.owner[bad]] = False
            if self.joint_groups:
                out[self._joint_false(mean[None, :], cov[None])[0]] = False
        return out

    def _joint_false(self, means: np.ndarray, covs: np.ndarray) -> np.ndarray:
        """Per step, which propositions a joint constraint makes false (Boole's bound > eps).

        Parameters
        ----------
        means : ndarray, shape (L, n)
        covs : ndarray, shape (L, n, n)

        Returns
        -------
        ndarray of bool, shape (L, num_atoms)
        """
        out = np.zeros((means.shape[0], self.num_atoms), dtype=bool)
        for i, rows, eps in self.joint_groups:
            H = self.H[rows]
            d = -(means @ H.T + self.c[rows])
            sd = np.sqrt(np.maximum(np.einsum("fi,tij,fj->tf", H, covs, H), 0.0))
            out[:, i] |= joint_tail_sum(d, sd) > eps
        return out

    def labels(self, means: np.ndarray, covs: np.ndarray, actions: np.ndarray, start: int = 0) -> np.ndarray:
        """:meth:`truth` of steps ``start..`` of a roll-out, batched over the steps (one
        ``std_terms`` call), shape (num_atoms, L - start).

        Parameters
        ----------
        means : ndarray, shape (L, n)
        covs : ndarray, shape (L, n, n)
        actions : ndarray of int, shape (L - 1,)
            ``actions[k - 1]`` is the mode that reached step ``k`` (step 0: none).
        start : int
        """
        L = len(means)
        if start >= L:
            return np.zeros((self.num_atoms, 0), dtype=bool)
        out = np.array([self._mode_truth(int(actions[k - 1]) if k else -1) for k in range(start, L)])
        if self.H.shape[0]:
            terms = std_terms(self.H, self.z, covs[start:])
            bad = (-(means[start:] @ self.H.T + self.c + terms) < 0) & ~self.joint_rows[None, :]
            rows, faces = np.nonzero(bad)
            out[rows, self.owner[faces]] = False
            if self.joint_groups:
                out[self._joint_false(means[start:], covs[start:])] = False
        return out.T

    def _mode_truth(self, arrival_mode: int) -> np.ndarray:
        """Which propositions a belief reached with ``arrival_mode`` may satisfy (cached per mode)."""
        cache: dict[int, np.ndarray] = self.__dict__.setdefault("_mode_truths", {})
        got = cache.get(arrival_mode)
        if got is None:
            got = np.ones(self.num_atoms, dtype=bool)
            if arrival_mode >= 0:
                for i, modes in enumerate(self.mode_sets):
                    if modes is not None and arrival_mode not in modes:
                        got[i] = False
            cache[arrival_mode] = got
        return got

    def region(self, i: int) -> Polytope:
        """Mean region of proposition ``i`` at zero covariance (whole space without faces; cached)."""
        cache: dict[int, Polytope] = self.__dict__.setdefault("_regions", {})
        if i not in cache:
            ap = self.atoms[i]
            if not ap.predicates:
                cache[i] = Polytope(np.zeros((0, self.n)), np.zeros(0))
            else:
                cache[i] = Polytope(ap.cone.H, ap.cone.c)
        return cache[i]

    def bounds(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Bounding box ``(low, high)`` of proposition ``i``'s mean region (cached; infinite where open)."""
        cache: dict[int, tuple[np.ndarray, np.ndarray]] = self.__dict__.setdefault("_bounds", {})
        if i not in cache:
            r = self.region(i)
            if not r.H.shape[0] or r.is_empty():
                cache[i] = (np.full(self.n, -np.inf), np.full(self.n, np.inf))
            else:
                cache[i] = r.bounding_box()
        return cache[i]

    def radius(self, i: int) -> float:
        """Chebyshev radius of proposition ``i``'s mean region (cached; ``inf`` without faces, and
        for a region holding balls as large as the Chebyshev LP's cap: an unbounded one)."""
        cache: dict[int, float] = self.__dict__.setdefault("_radii", {})
        if i not in cache:
            r = self.region(i)
            radius = np.inf if not r.H.shape[0] or r.is_empty() else r.chebyshev_center()[1]
            cache[i] = np.inf if radius >= 1e6 * (1 - 1e-9) else radius
        return cache[i]

    def out_of_reach(
        self,
        system: SwitchedSystem,
        initial_cov: np.ndarray,
        horizon: int,
        budget: Budget | None = None,
        max_steps: int = 5000,
    ) -> dict[int, str]:
        """Propositions whose confidence no reachable belief meets at any step ``1..horizon``.

        For a single-mode system the covariance schedule does not depend on the plan's inputs;
        with several modes sharing ``A`` the covariance floor over every switching sequence
        (:mod:`.covariance_floor`) bounds every plan's schedule from below; with state-dependent
        noise, the update with the noise's floor (``mode.noise_floor``)
        bounds it from below (the Riccati update is monotone in ``R`` and in the prior). A
        proposition whose region, shrunk by the *smallest* standard-deviation terms over the
        horizon, is empty cannot hold at any step. The schedule is rolled until it settles
        (or the horizon); a schedule still shrinking at ``max_steps`` proves nothing.
        """
        self.reach_proofs = {}
        if not self.num_atoms or horizon < 1:
            return {}
        steps = min(horizon, max_steps)
        every = ""
        if system.num_modes != 1:
            # Several modes: the floor over every switching sequence (where it is sound).
            from .covariance_floor import covariance_floor

            floor = covariance_floor(system.system_modes, initial_cov, steps, budget)
            if floor is None:
                return {}
            covs = floor.covs
            every = (
                f" (for every mode sequence: the covariance floor over all switching sequences; {floor.how})"
            )
        else:
            from .covariances import cached_schedule

            # Through the plan rows' cache: the lazy loop's candidates then reuse this schedule.
            covs, _ = cached_schedule(
                self, system.system_modes, initial_cov, np.zeros(steps, dtype=int), budget
            )
        tail = covs[1:]
        if steps < horizon:
            last, prev = tail[-1], tail[-2] if steps > 1 else initial_cov
            if np.abs(last - prev).max() > 1e-12 * (1.0 + np.abs(last).max()):
                return {}  # still changing: later steps could do better
        out: dict[int, str] = {}
        for i, ap in enumerate(self.atoms):
            if not ap.predicates:
                continue
            cone = ap.cone
            # A joint constraint's faces alone at its eps: necessary whatever the allocation.
            z = np.array(
                [
                    float(quantile(p.joint.eps)) if isinstance(p, JointFace) else cone.z[f]
                    for f, p in enumerate(ap.predicates)
                ]
            )
            terms = std_terms(cone.H, z, tail)  # (K, F)
            if np.any(np.isnan(terms)):
                continue  # no sound claim from a degenerate bound
            best = terms.min(axis=0)
            if not np.all(np.isfinite(best)):
                out[i] = f"{self.names()[i]} needs zero variance (eps = 0) but every step has some"
                # Per step: the face with eps = 0 and positive variance at that step's floor.
                f = int(np.flatnonzero(~np.isfinite(best))[0])
                for k in range(1, tail.shape[0] + 1):
                    self.reach_proofs[(i, k)] = FaceProof(
                        cone.H[f], float(cone.c[f]), float(cone.z[f]), np.zeros(self.n), tail[k - 1]
                    )
                self.reach_proofs[i] = NoProof(
                    f"{out[i]}: steps past {tail.shape[0]} rest on the covariance floor having settled"
                )
                continue
            region = Polytope(cone.H, cone.c + best)
            if region.is_empty():
                self.reach_proofs[i] = ModelProof(
                    _region_model(cone.H, cone.c + best),
                    f"{self.names()[i]} shrunk by the least standard-deviation terms of the covariance floor",
                )
                sd = float(np.sqrt(np.trace(tail[-1]) / tail.shape[1]))
                out[i] = (
                    f"the confidence of {self.names()[i]} is out of reach: even the smallest covariance "
                    f"a belief can have (a sound lower bound; rms std {sd:.3g} at the last step checked) "
                    f"leaves no mean inside it{every}"
                    + (
                        " (each face of a joint chance constraint alone at its eps, which every "
                        "risk allocation needs)"
                        if ap.joints
                        else ""
                    )
                )
        return out

    # -- pruning ------------------------------------------------------------------------------------
    def prune(
        self,
        system: SwitchedSystem,
        control_domain: Polytope,
        initial_mean: np.ndarray,
        initial_cov: np.ndarray,
        budget: Budget | None = None,
        max_step_lps: int = 400,
        backend: Backend | None = None,
        units: tuple[np.ndarray, np.ndarray] | None = None,
        reach: bool = False,
        max_gap: int = 0,
    ) -> PruningReport:
        """Prove letters empty, pairs disjoint and steps impossible (mean relaxation).

        Parameters
        ----------
        system : SwitchedSystem
        control_domain : Polytope
        initial_mean : ndarray, shape (n,)
        initial_cov : ndarray, shape (n, n)
        budget : Budget, optional
            Wall-clock cap (checked between LPs).
        max_step_lps : int
            Skip one-step pruning when it would take more LPs than this.
        backend : Backend, optional
            LP back-end for the one-step LPs (default HiGHS).
        units : (ndarray (n,), ndarray (m,)), optional
            Units of the state and input coordinates: the LPs are solved in them, with
            normalised rows, so that infeasibility is judged relative to the problem's scale.
        reach : bool
            Also prove multi-step gaps (:meth:`_impossible_gaps`) and take the one-step LPs over
            half-plane regions too (a door's "before" and "after" sides): more proven clauses,
            so the proposer offers fewer candidates a teacher must refute. Off by default: the
            extra clauses change which models the SAT solver returns first.
        max_gap : int
            The longest gap ``d`` tried (the formula's horizon: a longer one excludes nothing).
        """
        regions = [self.region(i) for i in range(self.num_atoms)]
        empty = [i for i, r in enumerate(regions) if r.H.shape[0] and r.is_empty()]
        disjoint: list[tuple[int, int]] = []
        for i in range(self.num_atoms):
            if budget is not None:
                budget.check("LP pruning")
            for j in range(i + 1, self.num_atoms):
                if i in empty or j in empty or not regions[i].H.shape[0] or not regions[j].H.shape[0]:
                    continue
                if regions[i].is_disjoint(regions[j]):
                    disjoint.append((i, j))
        init = self.truth(initial_mean, initial_cov, -1)
        initial_false = [i for i in range(self.num_atoms) if not init[i]]
        proofs: dict[tuple[object, ...], Proof] = {}
        for i in empty:
            proofs[("empty", i)] = ModelProof(
                _region_model(regions[i].H, regions[i].c), f"{self.names()[i]} is empty"
            )
        for i, j in disjoint:
            H = np.vstack([regions[i].H, regions[j].H])
            c = np.concatenate([regions[i].c, regions[j].c])
            proofs[("disjoint", i, j)] = ModelProof(
                _region_model(H, c), f"{self.names()[i]} and {self.names()[j]} are disjoint"
            )
        for i in initial_false:
            proofs[("initial", i)] = self._initial_proof(i, initial_mean, initial_cov)
        steps = self._impossible_steps(
            system,
            control_domain,
            regions,
            set(empty),
            budget,
            max_step_lps,
            backend or HighsBackend(),
            units,
            reach,
            proofs,
        )
        gaps: list[tuple[int, int, int]] = []
        roomless: list[tuple[int, int, int]] = []
        if reach and max_gap >= 2:
            first = [(i, j) for i, j, q in steps if q == -1]
            gaps, roomless = self._impossible_gaps(
                system,
                control_domain,
                regions,
                first,
                max_gap,
                budget,
                max_step_lps,
                backend or HighsBackend(),
                units,
                proofs,
            )
        report = PruningReport(
            empty, disjoint, steps, initial_false, impossible_gaps=gaps, roomless_gaps=roomless, proofs=proofs
        )
        logger.info(
            "LP pruning: %d empty letters, %d disjoint pairs, %d impossible steps, "
            "%d impossible gaps (%d without room), %d letters false at step 0",
            len(empty),
            len(disjoint),
            len(steps),
            len(gaps),
            len(roomless),
            len(initial_false),
        )
        return report

    def _impossible_gaps(
        self,
        system: SwitchedSystem,
        U: Polytope,
        regions: list[Polytope],
        first: list[tuple[int, int]],
        max_gap: int,
        budget: Budget | None,
        max_lps: int,
        backend: Backend,
        units: tuple[np.ndarray, np.ndarray] | None,
        proofs: dict[tuple[object, ...], Proof] | None = None,
    ) -> tuple[list[tuple[int, int, int]], list[tuple[int, int, int]]]:
        """Multi-step gaps: ``(proven, roomless)`` lists of ``(i, j, d)`` with ``d >= 2``.

        ``proven``: no mean in region ``i`` reaches region ``j`` in ``d`` steps. For each pair
        no mode can join in one step (``first``), ``d = 2, 3, ...`` until an LP is feasible.
        The modes must share ``A`` (else nothing is claimed): then ``x_d = A^d x_0 + sum_t
        A^(d-1-t) v_t`` with every ``v_t`` in the convex hull of the modes' ``B_q U`` (the
        perspective formulation ``v_t = sum_q B_q w_qt``, ``H w_qt + lambda_qt c <= 0``,
        ``sum_q lambda_qt = 1``): a relaxation of every mode sequence, so an infeasible LP is a
        proof.

        ``roomless``: no mean at region ``i``'s Chebyshev centre reaches region ``j``'s in ``d``
        steps (same relaxation; bounded regions only), for the ``d`` between the last proven gap
        and the first that reaches. Such a transition goes from edge to edge at full speed: no
        room for the execution's deviations (not a proof: the proposer only prefers plans
        without them). At most ``max_lps`` LPs in all, and ``d <= max_gap``.
        """
        modes = system.system_modes
        if not first or any(not np.array_equal(mode.A, modes[0].A) for mode in modes[1:]):
            return [], []
        proven: list[tuple[int, int, int]] = []
        roomless: list[tuple[int, int, int]] = []
        lps = 0
        for i, j in first:
            d = 2
            while d <= max_gap and lps < max_lps:
                if budget is not None:
                    budget.check("LP pruning")
                lps += 1
                models: list[LinearModel] = []
                if _reaches(system, U, regions[i], regions[j], d, backend, budget, units, models):
                    break
                proven.append((i, j, d))
                if proofs is not None and models:
                    names = self.names()
                    about = f"no mean in {names[i]} reaches {names[j]} in {d} steps (every mode sequence)"
                    proofs[("gap", i, j, d)] = ModelProof(models[0], about)
                d += 1
            if not (np.isfinite(self.radius(i)) and np.isfinite(self.radius(j))):
                continue
            ci, cj = _point(regions[i].chebyshev_center()[0]), _point(regions[j].chebyshev_center()[0])
            while d <= max_gap and lps < max_lps:
                if budget is not None:
                    budget.check("LP pruning")
                lps += 1
                if _reaches(system, U, ci, cj, d, backend, budget, units):
                    break
                roomless.append((i, j, d))
                d += 1
            else:
                # (no centre-to-centre route within the cap: claim nothing for this pair)
                roomless = [g for g in roomless if g[:2] != (i, j)]
        return proven, roomless

    def _impossible_steps(
        self,
        system: SwitchedSystem,
        U: Polytope,
        regions: list[Polytope],
        empty: set[int],
        budget: Budget | None,
        max_lps: int,
        backend: Backend,
        units: tuple[np.ndarray, np.ndarray] | None,
        reach: bool = False,
        proofs: dict[tuple[object, ...], Proof] | None = None,
    ) -> list[tuple[int, int, int]]:
        bounded, faced = [], []
        for i, r in enumerate(regions):
            if i in empty or not r.H.shape[0]:
                continue
            faced.append(i)
            low, high = r.bounding_box()
            if np.all(np.isfinite(low)) and np.all(np.isfinite(high)):
                bounded.append(i)
        pairs = [(i, j) for i in bounded for j in bounded if i != j]
        wide = [(i, j) for i in faced for j in faced if i != j]
        if reach and len(wide) * system.num_modes <= max_lps:
            pairs = wide  # half-planes too (the LPs are feasibility problems: unbounded is fine)
        if len(pairs) * system.num_modes > max_lps:
            logger.debug("skipping one-step pruning: %d pairs", len(pairs))
            return []
        out: list[tuple[int, int, int]] = []
        n, m = system.n, system.m
        for i, j in pairs:
            if budget is not None:
                budget.check("LP pruning")
            bad_modes = []
            refuted: list[Proof] = []
            for q, mode in enumerate(system.system_modes):
                # Variables (x, u): x in R_i, u in U, A x + B u in R_j.
                Ri, Rj = regions[i], regions[j]
                A_ub = np.vstack(
                    [
                        np.hstack([Ri.H, np.zeros((Ri.H.shape[0], m))]),
                        np.hstack([np.zeros((U.H.shape[0], n)), U.H]),
                        np.hstack([Rj.H @ mode.A, Rj.H @ mode.B]),
                    ]
                )
                b_ub = np.concatenate([-Ri.c, -U.c, -Rj.c])
                if units is not None:
                    A_ub = A_ub * np.concatenate(units)[None, :]
                norms = np.linalg.norm(A_ub, axis=1)
                norms = np.where(norms > 0, norms, 1.0)
                A_ub, b_ub = A_ub / norms[:, None], b_ub / norms
                model = LinearModel(
                    np.zeros(n + m),
                    csr_matrix(A_ub),
                    np.full(b_ub.shape[0], -np.inf),
                    b_ub,
                    np.full(n + m, -np.inf),
                    np.full(n + m, np.inf),
                )
                limit = budget.remaining() if budget is not None else 60.0
                if backend.solve(model, max(limit, 1e-3)).status == "infeasible":
                    bad_modes.append(q)
                    names = self.names()
                    refuted.append(
                        ModelProof(model, f"no mean in {names[i]} reaches {names[j]} in one step of mode {q}")
                    )
            if len(bad_modes) == system.num_modes:
                out.append((i, j, -1))
                if proofs is not None:
                    proofs[("step", i, j, -1)] = refuted[0] if len(refuted) == 1 else AllOf(refuted)
            else:
                out.extend((i, j, q) for q in bad_modes)
                if proofs is not None:
                    for q, proof in zip(bad_modes, refuted, strict=True):
                        proofs[("step", i, j, q)] = proof
        return out

    def _initial_proof(self, i: int, mean: np.ndarray, cov: np.ndarray) -> Proof:
        """The face of proposition ``i`` the initial belief violates (``initial_false``)."""
        ap = self.atoms[i]
        if not ap.predicates:
            return NoProof(f"{self.names()[i]} is false at step 0 without a face")
        cone = ap.cone
        slack = -(cone.H @ mean + cone.c + std_terms(cone.H, cone.z, cov))
        f = int(np.argmin(slack))
        return FaceProof(cone.H[f], float(cone.c[f]), float(cone.z[f]), mean, cov)


def _point(x: np.ndarray) -> Polytope:
    """The polytope ``{x}`` (two inequalities per coordinate)."""
    n = x.shape[0]
    return Polytope(np.vstack([np.eye(n), -np.eye(n)]), np.concatenate([-x, x]))


def _reaches(
    system: SwitchedSystem,
    U: Polytope,
    Ri: Polytope,
    Rj: Polytope,
    d: int,
    backend: Backend,
    budget: Budget | None,
    units: tuple[np.ndarray, np.ndarray] | None,
    models: list[LinearModel] | None = None,
) -> bool:
    """Whether some mean in ``Ri`` may reach ``Rj`` in ``d`` steps (the convex relaxation of
    :meth:`Abstraction._impossible_gaps`; the modes share ``A``). False only when the LP is
    infeasible (then the LP is appended to ``models``, for its proof)."""
    modes = system.system_modes
    A = modes[0].A
    n, m, Q = system.n, system.m, len(modes)
    xs, us = units if units is not None else (np.ones(n), np.ones(m))
    # Columns: x0 (n), then per step t and mode q: w_qt (m), lambda_qt (1). Built sparse, block
    # by block: the LP has O(d) rows and columns, and a dense build (O(d^2)) took 0.75 s at
    # d = 400, longer than a time limit may be overrun.
    width = n + d * Q * (m + 1)
    nu, ni, nj = U.H.shape[0], Ri.H.shape[0], Rj.H.shape[0]
    # A^s for s = 0..d (the last requirement's rows read A^(d-1-t) B_q and A^d).
    powers = [np.eye(n)]
    for _ in range(d):
        powers.append(A @ powers[-1])
    if budget is not None:
        budget.check("LP pruning")
    dom = coo_matrix(np.hstack([U.H, U.c[:, None]]))  # one (t, q) block of the domain rows
    blocks = d * Q
    # Domain rows: block b = t * Q + q occupies rows b * nu.. and columns n + b * (m + 1)...
    dom_rows = (np.arange(blocks)[:, None] * nu + dom.row[None, :]).ravel()
    dom_cols = (n + np.arange(blocks)[:, None] * (m + 1) + dom.col[None, :]).ravel()
    dom_vals = np.tile(dom.data, blocks)
    # Convexity rows: sum_q lambda_qt = 1 for each t.
    cvx_rows = np.repeat(np.arange(d), Q)
    cvx_cols = n + np.arange(blocks) * (m + 1) + m
    # The last requirement: Rj.H (A^d x0 + sum_t A^(d-1-t) sum_q B_q w_qt) <= -Rj.c.
    last = np.zeros((nj, width))
    last[:, :n] = Rj.H @ powers[d]
    for t in range(d):
        for q, mode in enumerate(modes):
            c0 = n + (t * Q + q) * (m + 1)
            last[:, c0 : c0 + m] = Rj.H @ powers[d - 1 - t] @ mode.B
    rows_dom = d * Q * nu
    M = vstack(
        [
            csr_matrix(np.hstack([Ri.H, np.zeros((ni, width - n))])),
            csr_matrix((dom_vals, (dom_rows, dom_cols)), shape=(rows_dom, width)),
            csr_matrix((np.ones(blocks), (cvx_rows, cvx_cols)), shape=(d, width)),
            csr_matrix(last),
        ],
        format="csr",
    )
    lo = np.concatenate([np.full(ni, -np.inf), np.full(rows_dom, -np.inf), np.ones(d), np.full(nj, -np.inf)])
    hi = np.concatenate([-Ri.c, np.zeros(rows_dom), np.ones(d), -Rj.c])
    scale = np.concatenate([xs, np.tile(np.concatenate([us, [1.0]]), d * Q)])
    M = csr_matrix(M @ diags(scale))
    norms = np.sqrt(np.asarray(M.multiply(M).sum(axis=1)).ravel())
    norms = np.where(norms > 0, norms, 1.0)
    col_lo = np.full(width, -np.inf)
    col_lo[n + np.arange(d * Q) * (m + 1) + m] = 0.0
    model = LinearModel(
        np.zeros(width),
        csr_matrix(diags(1.0 / norms) @ M),
        lo / norms,
        hi / norms,
        col_lo,
        np.full(width, np.inf),
    )
    limit = budget.remaining() if budget is not None else 60.0
    reaches = bool(backend.solve(model, max(limit, 1e-3)).status != "infeasible")
    if not reaches and models is not None:
        models.append(model)
    return reaches


def _region_model(H: np.ndarray, c: np.ndarray) -> LinearModel:
    """The LP ``H x <= -c`` (a region ``H x + c <= 0``), for the proof of its emptiness."""
    n = H.shape[1]
    return LinearModel(
        np.zeros(n),
        csr_matrix(H),
        np.full(H.shape[0], -np.inf),
        -np.asarray(c, dtype=float),
        np.full(n, -np.inf),
        np.full(n, np.inf),
    )
