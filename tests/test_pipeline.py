"""The solve pipeline as one visible list (issue 33)."""

from __future__ import annotations

import idstlpy as stl
from idstlpy.synthesis import pipeline


def test_the_pipeline_lists_its_stages_in_order():
    names = [stage.name for stage in pipeline.STAGES]
    assert names == [
        "decoupled",
        "search",
        "joint allocation",
        "closed-loop fallback",
        "chance switching bound",
    ]
    # the fallback stage runs only where its docstring says
    fallback = pipeline.STAGES[3]
    assert fallback.applies(stl.SolverOptions.make())
    assert not fallback.applies(stl.SolverOptions.make(first_found=True))
    assert not fallback.applies(stl.SolverOptions.make(guarantee="mlo"))
