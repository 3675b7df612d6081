"""``python -m catenary.cli``: the ``catenary`` command."""

from catenary.cli import main

main()
