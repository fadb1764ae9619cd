from sb3_pola.pola.pola import POLA
from sb3_pola.pola.policies import MlpPolicy, POLAPolicy

__all__ = ["POLA", "MlpPolicy", "POLAPolicy"]
