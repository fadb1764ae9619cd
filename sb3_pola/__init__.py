import pathlib

from sb3_pola.pola import PAPER_FORM, POLA, MlpPolicy, POLAPolicy

__version__ = (pathlib.Path(__file__).parent / "version.txt").read_text().strip()

__all__ = ["PAPER_FORM", "POLA", "MlpPolicy", "POLAPolicy", "__version__"]
