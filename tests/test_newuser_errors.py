"""Errors a new user met in the README trial, each naming what is wrong."""

from __future__ import annotations

import numpy as np
import pytest

import idstlpy as stl


def test_to_belief_says_mean_and_cov_disagree():
    with pytest.raises(stl.DimensionError, match=r"mean has 3 entries but cov is 2 x 2"):
        stl.to_belief(mean=np.zeros(3), cov=np.eye(2))


def test_parse_formula_names_an_atom_given_as_none():
    x = stl.mk_variable(1, float)
    goal = stl.logical_and(stl.prob(x[0] >= 0) >= 0.9, name="goal")
    with pytest.raises(stl.FormulaSyntaxError, match=r"'safe' is None in atoms"):
        stl.parse_formula("(safe U[0,3] goal)", atoms={"safe": None, "goal": goal})
