import os

from sb3_pola.pola import PAPER_FORM, POLA, MlpPolicy, POLAPolicy

__version__ = open(os.path.join(os.path.dirname(__file__), "version.txt")).read().strip()

__all__ = ["PAPER_FORM", "POLA", "MlpPolicy", "POLAPolicy", "__version__"]
