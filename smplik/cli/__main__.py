"""``python -m smplik.cli``: the same as the ``smplik`` console script."""

from smplik.cli import main

main()
