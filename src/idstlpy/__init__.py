"""idstlpy: active perception and control synthesis from PrSTL for switched linear systems.

The public API follows the idSTLPy paper (da Silva, Yadav, Lin): variables and predicates,
PrSTL formulas, switched belief systems, ``Problem.solve`` and ``SwitchedSystem.simulate``.
"""

import logging as _logging

from . import dynamical_system
from ._version import __version__
from .belief import GaussianBelief, belief_step, rollout, to_belief
from .continuous import Discretization, cov_factor, discretize, from_continuous
from .dynamical_system import (
    LBS,
    LCS,
    POLBS,
    DynamicalSystem,
    POLBSWithLinNoise,
    POLBSWithNonLinNoise,
    SwitchedSystem,
    mk_lbs,
    mk_lcs,
    mk_switched_sys,
)
from .errors import (
    DimensionError,
    ExecutionTargetWarning,
    IdstlpyError,
    InvalidArgumentError,
    InvalidTypeError,
    NoiseFunctionError,
    OutOfRangeError,
    ProblemFileError,
)
from .execution import (
    ClosedLoopPrediction,
    ExecutionReport,
    Replan,
    ReplanningExecutor,
    ReplanPolicy,
    StartCheck,
    ValidationReport,
    execute,
    finite_horizon_lqr,
    predict_closed_loop,
    simulate,
    start_check,
    validate,
)
from .execution_target import ExecutionTarget
from .executor import ExecutorSpec, OnlineExecutor
from .executor.jump_online import JumpExecutor
from .executor.markov_bound import MarkovBound, markov_bound
from .expressions import (
    ConvexConstraint,
    ConvexRegion,
    DiscretePredicate,
    DiscreteVariable,
    JointChanceConstraint,
    LinearExpression,
    LinearPredicate,
    ProbabilisticLinearPredicate,
    RealValuedVariable,
    mk_variable,
    prob,
    prob_in,
)
from .formulas import (
    FALSE,
    TRUE,
    STLAnd,
    STLAtomicProposition,
    STLFormula,
    STLOr,
    STLRelease,
    STLTemporalFormula,
    STLUntil,
    always,
    eventually,
    logical_and,
    logical_or,
    release,
    until,
)
from .markov import MarkovSwitching, mk_markov_switching, with_switching
from .problem_file import ProblemSpec, apply_overrides, load_problem
from .progression import progress
from .semantics import MonitorReport, monitor, robustness, satisfies
from .sets import (
    BeliefCone,
    FullDimensionalBeliefCone,
    FullDimensionalPolytope,
    Polytope,
)
from .syntax import FormulaSyntaxError, parse_formula
from .synthesis import (
    Problem,
    SearchProgress,
    SolveResult,
    SolverOptions,
    SolveStats,
    Termination,
    load_result,
)
from .trajectory import ProbabilisticTSTrajectory, RealTrajectory

_logging.getLogger(__name__).addHandler(_logging.NullHandler())
del _logging

__all__ = [
    "__version__",
    # variables and predicates
    "mk_variable",
    "prob",
    "prob_in",
    "JointChanceConstraint",
    "LinearExpression",
    "RealValuedVariable",
    "DiscreteVariable",
    "ConvexConstraint",
    "LinearPredicate",
    "ProbabilisticLinearPredicate",
    "DiscretePredicate",
    "ConvexRegion",
    # sets
    "Polytope",
    "FullDimensionalPolytope",
    "BeliefCone",
    "FullDimensionalBeliefCone",
    # formulas
    "STLFormula",
    "STLAtomicProposition",
    "STLAnd",
    "STLOr",
    "STLTemporalFormula",
    "STLUntil",
    "STLRelease",
    "TRUE",
    "FALSE",
    "logical_and",
    "logical_or",
    "until",
    "eventually",
    "release",
    "always",
    # systems and beliefs
    "dynamical_system",
    "DynamicalSystem",
    "LCS",
    "LBS",
    "POLBS",
    "POLBSWithLinNoise",
    "POLBSWithNonLinNoise",
    "SwitchedSystem",
    "mk_lcs",
    "mk_lbs",
    "mk_switched_sys",
    "from_continuous",
    "discretize",
    "Discretization",
    "cov_factor",
    "GaussianBelief",
    "to_belief",
    "belief_step",
    "rollout",
    # synthesis
    "Problem",
    "SolveResult",
    "SolverOptions",
    "Termination",
    "SearchProgress",
    "load_result",
    "SolveStats",
    # execution
    "OnlineExecutor",
    "ReplanningExecutor",
    "ReplanPolicy",
    "ExecutorSpec",
    "finite_horizon_lqr",
    "simulate",
    "validate",
    "execute",
    "ExecutionReport",
    "Replan",
    "start_check",
    "StartCheck",
    "progress",
    "predict_closed_loop",
    # chance switching (issue 35)
    "MarkovSwitching",
    "mk_markov_switching",
    "with_switching",
    "MarkovBound",
    "markov_bound",
    "JumpExecutor",
    "ClosedLoopPrediction",
    "ValidationReport",
    "ExecutionTarget",
    # problem files and text syntax
    "load_problem",
    "apply_overrides",
    "ProblemSpec",
    "parse_formula",
    "FormulaSyntaxError",
    # trajectories and monitoring
    "ProbabilisticTSTrajectory",
    "RealTrajectory",
    "monitor",
    "MonitorReport",
    "robustness",
    "satisfies",
    # errors
    "IdstlpyError",
    "InvalidArgumentError",
    "InvalidTypeError",
    "DimensionError",
    "OutOfRangeError",
    "NoiseFunctionError",
    "ProblemFileError",
    "ExecutionTargetWarning",
]
