"""Issue #23's screen of the confident choice moved into training: the Q term only at the states where the critic's
members agree the actor's action beats the data's (a screen, not a package option).

At each actor step, for each state ``s`` of the batch with data action ``a``: ``d_j = Q_j(s, pi(s)) - Q_j(s, a)``
over the critic's members (no gradient); the state's terms of eq. 3/4 (the current and its predicted states) count
only where ``mean_j d_j > k std_j d_j``; elsewhere the actor only imitates. The package's option
``fallback_confidence`` makes the same test at ``predict`` between two actors; this makes it while training one.

    GATE_K=1 python experiments/policy_quality/confident_q_term.py --dataset hopper/medium-v0 --name G1 \\
        --rules mode --kwargs '{"compile_update": false, ...}'

Arguments as ``screen.py`` (whose ``main`` runs with the gated class); ``GATE_K`` is ``k``. Eager only
(``"compile_update": false``). ``train/gate_share`` in the run's ``progress.csv``: the fraction of the batch whose Q
term counted.
"""

from __future__ import annotations

import os
import pathlib
import sys
from typing import Any

import torch as th

import sb3_pola.pola.pola as pola_module
from sb3_pola import POLA

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import screen

_objective = pola_module.lookahead_q_objective


class ConfidentQTerm(POLA):
    """POLA whose Q term counts only at the states where the members agree the actor's action beats the data's."""

    gate_k: float = 1.0
    _gate: dict[str, th.Tensor] | None = None

    def _bc_loss(self, obs: th.Tensor, actions: th.Tensor, weight_temp: th.Tensor) -> Any:
        self._gate_actions = actions  # the actor step's data actions, read by _q_term next
        return super()._bc_loss(obs, actions, weight_temp)

    def _q_term(self, obs: th.Tensor, eta: th.Tensor) -> Any:
        with th.no_grad():  # the critic is frozen here; [N, B] at the data's actions
            self._gate = {"q_data": self.critic(obs, self._gate_actions)}
        global _active
        _active = self
        try:
            loss, stats = super()._q_term(obs, eta)
        finally:
            _active = None
        stats["gate_share"] = self._gate["share"]
        return loss, stats


_active: ConfidentQTerm | None = None


def gated_objective(q: th.Tensor, alive: th.Tensor, *args: Any, **kwargs: Any) -> Any:
    """``lookahead_q_objective`` with each state's terms masked by the members' test (``q``: ``[N, T+1, B]``)."""
    if _active is None or _active._gate is None:
        return _objective(q, alive, *args, **kwargs)
    gain = q[:, 0].detach() - _active._gate["q_data"]  # [N, B]: d_j at each state
    confident = (gain.mean(dim=0) > _active.gate_k * gain.std(dim=0)).to(alive.dtype)  # [B]
    _active._gate["share"] = confident.mean()
    return _objective(q, alive * confident, *args, **kwargs)


pola_module.lookahead_q_objective = gated_objective  # type: ignore[assignment]

if __name__ == "__main__":
    ConfidentQTerm.gate_k = float(os.environ.get("GATE_K", "1"))
    screen.POLA = ConfidentQTerm  # type: ignore[misc]
    screen.main()
