"""``python -m softsbi.cli``: the same as the ``softsbi`` command."""
from . import main

main()
