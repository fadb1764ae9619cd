"""``python -m sb3_pola.collect``."""

import sys

from sb3_pola.collect import main

sys.exit(main())
