"""``python -m sb3_pola.cli``: the ``sb3-pola`` command."""

import sys

from sb3_pola.cli import main

sys.exit(main())
