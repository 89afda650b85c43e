"""``python -m softsbi.cli``: the same as the ``softsbi`` command."""
from softsbi.cli import main

main()
