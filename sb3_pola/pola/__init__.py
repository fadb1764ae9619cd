from sb3_pola.pola.policies import MlpPolicy, POLAPolicy
from sb3_pola.pola.pola import POLA

__all__ = ["POLA", "MlpPolicy", "POLAPolicy"]
