"""``python bench/fem_study.py``: the same as ``deapull fem-study`` (workflows/fem_study.py)."""
from deapull.workflows.fem_study import main

if __name__ == "__main__":
    raise SystemExit(main())
