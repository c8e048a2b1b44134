"""``python -m idstlpy``: the ``idstlpy`` command (:func:`idstlpy.cli.main`), for environments whose
scripts directory is not on ``PATH`` (a virtual environment that is not activated)."""

from __future__ import annotations

from .cli import main

if __name__ == "__main__":
    raise SystemExit(main())
