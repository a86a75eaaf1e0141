"""``python -m deapull.workflows`` / ``deapull``: the command-line entry point."""
from deapull.workflows.cli import main

if __name__ == "__main__":
    raise SystemExit(main())
