"""Synthesis: the counterexample-guided loop of BMC proposer and continuous teachers."""

from .options import SolverOptions, Termination
from .problem import Problem, solve
from .results import SolveResult, SolveStats, load_result
from .termination import SearchProgress

__all__ = [
    "Problem",
    "SearchProgress",
    "SolveResult",
    "SolveStats",
    "SolverOptions",
    "Termination",
    "load_result",
    "solve",
]
