"""Synthesis: the counterexample-guided loop of BMC proposer and continuous teachers."""

from .options import SolverOptions, Termination
from .problem import Problem, solve
from .results import SolveResult, SolveStats, load_result

__all__ = ["Problem", "SolveResult", "SolveStats", "SolverOptions", "Termination", "load_result", "solve"]
