"""Synthesis: the counterexample-guided loop of BMC proposer and continuous teacher."""

from .problem import Problem, SolveResult, SolveStats

__all__ = ["Problem", "SolveResult", "SolveStats"]
