"""``python -m workflows`` / ``deapull``: the command-line entry point."""
from workflows.cli import main

if __name__ == "__main__":
    raise SystemExit(main())
