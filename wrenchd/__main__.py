"""``python -m wrenchd``: the ``wrenchd`` command line."""

from wrenchd.service.cli import main

if __name__ == "__main__":
    raise SystemExit(main())
