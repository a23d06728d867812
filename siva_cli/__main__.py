"""``python -m siva_cli ...`` runs the ``siva`` program."""
import sys

from . import main

sys.exit(main())
