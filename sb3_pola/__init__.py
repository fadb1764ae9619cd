import os

from sb3_pola.pola import POLA, MlpPolicy, POLAPolicy

__version__ = open(os.path.join(os.path.dirname(__file__), "version.txt")).read().strip()

__all__ = ["POLA", "MlpPolicy", "POLAPolicy", "__version__"]
