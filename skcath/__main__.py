"""Entry point of ``python -m skcath``; see :mod:`skcath._cli`."""

from ._cli import main

if __name__ == "__main__":
    raise SystemExit(main())
