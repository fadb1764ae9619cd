from sb3_pola.pola.pola import PAPER_FORM, POLA
from sb3_pola.pola.policies import MlpPolicy, POLAPolicy

__all__ = ["PAPER_FORM", "POLA", "MlpPolicy", "POLAPolicy"]
