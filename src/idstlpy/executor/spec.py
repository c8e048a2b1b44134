"""What runs a plan: one frozen, validated description of the executor.

:class:`ExecutorSpec` gathers the settings that used to travel as repeated keywords of
``simulate``, ``validate``, ``execute`` and the predictions (``control_domain``,
``process_noise``, ``lqr_gains``, ``default_lqr``, ``real_system``) and resolves them once:

- the tracking gains of every mode (the caller's ``lqr_gains``, else the mode's
  ``lqr_gains``, else ``default_lqr``'s weights, else the gains the plan was made for
  (``plan.tracking``), else :data:`idstlpy.tracking.DEFAULT_LQR` weights), computed at construction;
- the projection of an input on the control domain;
- the plant that moves the true state: the model itself, a linear switched system (one mode for
  all, or one per planning mode) or any step function ``(state, input, mode, rng) -> next_state``
  (a nonlinear robot, a simulator);
- which process noise disturbs the true state (``"auto"``, the default: the real system's own
  disturbance when its modes declare one, else the planning mode's; ``"model"``: the planning
  mode's ``W w``; ``"real"``: the real linear mode's ``W w``; ``"none"``).
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, fields
from types import MappingProxyType
from typing import Any, Literal

import numpy as np

from ..closed_loop import real_modes_for
from ..dynamical_system import LBS, LCS, SwitchedSystem, control_domain_mismatch
from ..errors import DimensionError, InvalidArgumentError, InvalidTypeError
from ..sets import Polytope
from ..tracking import GainsOverride, box_bounds, control_projector, plan_fallback, system_gains
from ..trajectory import ProbabilisticTSTrajectory

__all__ = [
    "PLANT_SIGNATURE",
    "ExecutorSpec",
    "PlantStep",
    "ProcessNoise",
    "check_plant_signature",
    "resolve_process_noise",
]

ProcessNoise = Literal["auto", "model", "real", "none"]
"""Which disturbance moves the true state (:func:`resolve_process_noise` reads ``"auto"``)."""


def resolve_process_noise(
    process_noise: ProcessNoise | str, real_system: SwitchedSystem | LCS | None
) -> Literal["model", "real", "none"]:
    """The process-noise reading an executor runs: ``"auto"`` resolved, any other value checked.

    ``"auto"`` (the default everywhere) is ``"real"`` when a linear ``real_system`` is given
    whose modes all declare their own disturbance (made by :func:`~idstlpy.mk_lbs`, ``W`` possibly
    zero), and ``"model"`` otherwise (no real system, a noise-free :func:`~idstlpy.mk_lcs` plant,
    or a step-function plant). A real system's ``W`` is what the user says the world does; the
    planning model's used to replace it silently, so a stress test with a noisier plant measured
    the nominal rate.

    Raises
    ------
    InvalidArgumentError
        When ``process_noise`` is not one of ``"auto"``, ``"model"``, ``"real"``, ``"none"``.
    """
    if process_noise == "auto":
        modes = (
            [real_system]
            if isinstance(real_system, LCS)
            else list(real_system.system_modes)
            if isinstance(real_system, SwitchedSystem)
            else []
        )
        return "real" if modes and all(isinstance(mode, LBS) for mode in modes) else "model"
    if process_noise in ("model", "real", "none"):
        return process_noise  # type: ignore[return-value]  # narrowed by the test above
    raise InvalidArgumentError(
        f"process_noise must be 'auto', 'model', 'real' or 'none', got {process_noise!r}"
    )


"""Which process noise disturbs the true state."""

PlantStep = Callable[[np.ndarray, np.ndarray, int, np.random.Generator], Any]
"""A plant given as a step function: ``(state (n,), input (m,), planning mode, rng) -> next state (n,)``."""


@dataclass(frozen=True)
class ExecutorSpec:
    """A frozen description of what runs a plan (build it with :meth:`make`).

    Attributes
    ----------
    system : SwitchedSystem
        The planning model: its sensors make the observations, its matrices run the filter.
    control_domain : Polytope or None
        Admissible inputs (dimension ``m``); the corrected input is projected on it.
    process_noise : {"model", "real", "none"}
        Which disturbance moves the true state (``"auto"`` already resolved).
    gains : mapping int -> tuple of ndarray (m, n)
        The tracking gains ``K_0 .. K_{h-1}`` of every mode, resolved once.
    real_modes : tuple of LCS or None
        The linear plant's modes (one for all, or one per planning mode); None for a step plant.
    plant_step : callable or None
        The plant as a step function ``(state, input, mode, rng) -> next_state``; None for a
        linear plant.
    defaulted : frozenset of int
        The modes whose gains nobody chose (no ``lqr_gains``, no gains of the mode's own, no
        ``default_lqr``, no plan's): a plan run with this spec tracks them with the gains it
        was made for (:meth:`gains_for`).
    """

    system: SwitchedSystem
    control_domain: Polytope | None
    process_noise: ProcessNoise
    gains: Mapping[int, tuple[np.ndarray, ...]]
    real_modes: tuple[LCS, ...] | None
    plant_step: PlantStep | None
    box: tuple[np.ndarray, np.ndarray] | None = field(repr=False)
    project: Callable[[np.ndarray], np.ndarray] = field(repr=False)
    defaulted: frozenset[int] = frozenset()

    @classmethod
    def make(
        cls,
        system: SwitchedSystem,
        *,
        control_domain: Polytope | None = None,
        process_noise: ProcessNoise = "auto",
        lqr_gains: GainsOverride = None,
        default_lqr: Mapping[str, Any] | None = None,
        real_system: SwitchedSystem | LCS | None = None,
        plant: PlantStep | None = None,
        modes: Iterable[int] | None = None,
    ) -> ExecutorSpec:
        """Validate the executor's settings and resolve the tracking gains once.

        Parameters
        ----------
        system : SwitchedSystem
            The planning model.
        control_domain : Polytope, optional
            Admissible inputs (dimension ``m``); None applies the corrected input unclipped.
        process_noise : {"auto", "model", "real", "none"}
            Disturbance of the true state: ``"auto"`` (default) the real linear modes' ``W w``
            when they declare one (made by ``mk_lbs``), else the planning mode's
            (:func:`resolve_process_noise`); ``"model"`` the planning mode's ``W w``, ``"real"``
            the real linear mode's ``W w`` (a linear ``real_system`` only), ``"none"`` none. A step-function
            ``plant`` draws its own disturbance from the generator it is given; ``"model"`` then
            adds the planning mode's ``W w`` on top, ``"none"`` nothing.
        lqr_gains : mapping or sequence, optional
            Per mode, gains (m, n) overriding ``mode.lqr_gains``.
        default_lqr : mapping, optional
            Weights for modes without gains (see :data:`idstlpy.tracking.DEFAULT_LQR`).
        real_system : SwitchedSystem or LCS, optional
            A linear plant (one mode for all, or one per planning mode); default the model.
        plant : callable, optional
            A plant given as a step function ``(state, input, mode, rng) -> next_state``
            (shapes (n,), (m,), int, ``numpy.random.Generator`` -> (n,)); exclusive with
            ``real_system``.
        modes : iterable of int, optional
            The modes whose gains are resolved (default all).

        Returns
        -------
        ExecutorSpec

        Raises
        ------
        InvalidTypeError, DimensionError, InvalidArgumentError
            Naming the argument that is wrong.
        """
        if not isinstance(system, SwitchedSystem):
            raise InvalidTypeError(f"system must be a SwitchedSystem, got {type(system).__name__}")
        process_noise = resolve_process_noise(process_noise, real_system)
        if isinstance(control_domain, Polytope) and control_domain.dim != system.m:
            raise control_domain_mismatch(control_domain.dim, system)
        project = control_projector(control_domain, system.m)
        box = box_bounds(control_domain, system.m)
        real_modes = _real_modes(system, real_system, plant, process_noise)
        # the modes nobody chose gains for: the paper's here, the plan's when it runs (gains_for)
        fallback = plan_fallback(system, None)
        frozen = _frozen_gains(system_gains(system, lqr_gains, default_lqr, modes, fallback))
        given = _given_gains(system, lqr_gains)
        defaulted = frozenset(
            q
            for q in frozen
            if default_lqr is None
            and q not in given
            and getattr(system.mode(q), "lqr_gains", None) is None
            and (fallback is None or q not in fallback)
        )
        return cls(
            system=system,
            control_domain=control_domain,
            process_noise=process_noise,
            gains=MappingProxyType(frozen),
            real_modes=real_modes,
            plant_step=plant,
            box=box,
            project=project,
            defaulted=defaulted,
        )

    def __getstate__(self) -> dict[str, Any]:
        """Picklable (process pools): the read-only mapping and the projector are rebuilt."""
        state = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "project"}
        state["gains"] = dict(self.gains)
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        for K in (K for Ks in state["gains"].values() for K in Ks):
            K.flags.writeable = False
        for name, value in state.items():
            object.__setattr__(self, name, value)
        object.__setattr__(self, "gains", MappingProxyType(state["gains"]))
        object.__setattr__(self, "project", control_projector(state["control_domain"], state["system"].m))

    def gains_for(self, plan: ProbabilisticTSTrajectory) -> Mapping[int, tuple[np.ndarray, ...]]:
        """The gains that track ``plan``: :attr:`gains`, with the modes nobody chose gains for
        (:attr:`defaulted`) tracked as the plan was made for (``plan.tracking``), so a spec made
        before the plan runs the loop the planner predicted.

        Parameters
        ----------
        plan : ProbabilisticTSTrajectory

        Returns
        -------
        mapping int -> tuple of ndarray (m, n)
        """
        own = plan.tracking
        if own is None or not self.defaulted:
            return self.gains
        return MappingProxyType(
            {
                q: (own.gains[q] if q in self.defaulted and q in own.gains else Ks)
                for q, Ks in self.gains.items()
            }
        )

    def check_plan_modes(self, actions: np.ndarray) -> None:
        """Raise :class:`DimensionError` when a plan uses a mode the plant or the gains lack."""
        if not actions.size:
            return
        top = int(actions.max())
        if int(actions.min()) < 0 or top >= self.system.num_modes:
            raise DimensionError(
                f"the plan uses modes {sorted(set(actions.tolist()))}, "
                f"the system has 0..{self.system.num_modes - 1}"
            )
        if self.real_modes is not None and len(self.real_modes) > 1 and top >= len(self.real_modes):
            raise DimensionError(
                f"the plan uses mode {top}, real_system has modes 0..{len(self.real_modes) - 1} "
                "(give one real mode per planning mode, or a single mode used for all)"
            )
        missing = sorted(set(actions.tolist()) - set(self.gains))
        if missing:
            raise InvalidArgumentError(f"the executor has no tracking gains for modes {missing}")


def _real_modes(
    system: SwitchedSystem,
    real_system: SwitchedSystem | LCS | None,
    plant: PlantStep | None,
    process_noise: ProcessNoise,
) -> tuple[LCS, ...] | None:
    """The linear plant's modes (None for a step-function ``plant``, after checking it)."""
    if plant is None:
        return tuple(real_modes_for(real_system, system, np.zeros(0, dtype=int)))
    if real_system is not None:
        raise InvalidArgumentError("give either real_system (a linear plant) or plant (a step function)")
    if not callable(plant):
        raise InvalidTypeError(
            f"plant must be a step function (state, input, mode, rng) -> next_state, "
            f"got {type(plant).__name__}"
        )
    check_plant_signature(plant)
    if process_noise == "real":
        raise InvalidArgumentError(
            "process_noise='real' needs a linear real_system; a step-function plant draws its own "
            "disturbance (use 'none', or 'model' to add the planning mode's W w)"
        )
    return None


PLANT_SIGNATURE = "plant(state (n,), input (m,), mode: int, rng: numpy.random.Generator) -> next_state (n,)"
"""The call every step-function plant must accept (named in the error when it does not)."""


def check_plant_signature(plant: Callable[..., Any]) -> None:
    """Raise :class:`InvalidTypeError` unless ``plant`` accepts the four positional arguments.

    The executor calls ``plant(state, input, mode, rng)`` positionally once per run and step; a
    function written as ``plant(x, u)`` or ``plant(x, u, q, rng, dt)`` would otherwise fail
    with a raw ``TypeError`` from deep inside the simulation loop, after the plan was solved.

    Parameters
    ----------
    plant : callable
        The step function to check.

    Raises
    ------
    InvalidTypeError
        When ``plant`` cannot be called with four positional arguments (or needs a keyword-only
        one); the message names the expected call and the function's own signature.
    """
    try:
        sig = inspect.signature(plant)
    except (TypeError, ValueError):
        return  # some builtins and C extensions publish no signature: nothing to check up front
    try:
        sig.bind(None, None, None, None)
    except TypeError as exc:
        name = getattr(plant, "__qualname__", type(plant).__name__)
        raise InvalidTypeError(
            f"plant must be callable as {PLANT_SIGNATURE}; {name}{sig} cannot be called with "
            f"these four positional arguments ({exc}); a plant that needs no mode or noise still "
            "takes them: def plant(x, u, q, rng): ..."
        ) from None


def _given_gains(system: SwitchedSystem, lqr_gains: GainsOverride) -> set[int]:
    """The modes ``lqr_gains`` gives gains for."""
    if lqr_gains is None:
        return set()
    if isinstance(lqr_gains, Mapping):
        return {int(q) for q, Ks in lqr_gains.items() if Ks is not None}
    return {q for q, Ks in enumerate(lqr_gains) if Ks is not None and q < system.num_modes}


def _frozen_gains(gains: Mapping[int, Sequence[np.ndarray]]) -> dict[int, tuple[np.ndarray, ...]]:
    """Read-only copies of every mode's gains (a spec is shared by runs and threads)."""
    frozen = {}
    for q, Ks in gains.items():
        arrays = []
        for K in Ks:
            K = np.array(K, dtype=float)
            K.flags.writeable = False
            arrays.append(K)
        frozen[q] = tuple(arrays)
    return frozen
