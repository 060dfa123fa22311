"""The state estimator (docs/METHOD.md "Network of one agent" and "Estimator loss", paper eq. 3).

An MLP that predicts, from an agent's mental map ``M_{k-1}``, the uncertainty of every node at the
next step, ``û`` (the u channel of ``M_k``). Design decisions (docs/METHOD.md leaves them open):

* **Per node, weights shared across nodes.** Each node's prediction reads only that node's row
  ``[u/u_max, age/max_cycles, target, occupied, self]``; the same MLP serves every node, so it has
  the same size on any graph and can generalize across nodes. A node's next ``u`` depends mostly on
  its own row (last seen value, how stale it is, whether the agent is on it), which is what this
  captures.
* **Targets only.** The output is multiplied by the map's target flag: a node not known to be a
  target has ``u = 0`` in the map and in the world, so predicting anything else can only hurt.
* **Scale.** The network works in units of ``u / u_max``; :meth:`StateEstimator.forward` returns
  ``û`` in units of ``u`` (clamped to ``[0, u_max]``), and the loss is the MSE in ``u / u_max``
  units so that its scale does not depend on ``u_max``.
* **Targets of the loss**: every node of ``M_k``, as in the paper.
"""

from __future__ import annotations

from collections.abc import Sequence
from itertools import islice

import numpy as np
import torch as th
from torch import nn

from sb3_pm.envs.mental_map import TARGET, U

#: Batches with at least this many node rows run the MLP on known targets' rows only.
GATHER_MIN_ROWS = 1024


class StateEstimator(nn.Module):
    """Per-node MLP ``M_{k-1} -> û_k``.

    :param n_features: node feature columns of the map (5, plus one each for ``territory_input``
        and ``advice_input``).
    :param u_max: the cap on ``u`` (the nodes space's high of column ``u``).
    :param inv_high: ``(N, n_features)`` reciprocal highs used to normalize the map.
    :param hidden: hidden layer sizes.

    Shapes:
        - nodes: ``(B, N, n_features)`` raw map features
        - output: ``(B, N)`` predicted ``u`` (``forward``) or ``u / u_max`` (``forward_normalized``)
    """

    def __init__(
        self, n_features: int, u_max: float, inv_high: th.Tensor, hidden: Sequence[int] = (64, 64)
    ) -> None:
        super().__init__()
        self.n_features, self.u_max, self.hidden = n_features, float(u_max), tuple(hidden)
        self.inv_high: th.Tensor
        self.register_buffer("inv_high", inv_high.clone().float())
        layers: list[nn.Module] = []
        size = n_features
        for width in self.hidden:
            layers += [nn.Linear(size, width), nn.ReLU()]
            size = width
        layers.append(nn.Linear(size, 1))
        self.net = nn.Sequential(*layers)

    def forward_normalized(self, nodes: th.Tensor) -> th.Tensor:
        """``û / u_max`` before clamping (what the loss is computed on).

        The output is multiplied by the target flag, so only known targets' rows matter: on large
        batches (PPO's minibatches, the estimator's own fit) the MLP runs on those rows alone, about
        1/6 of them on the paper's graphs; values and gradients are the same as over every row.
        """
        target = nodes[..., TARGET]
        if target.numel() < GATHER_MIN_ROWS:  # a rollout step: indexing would cost more than it saves
            return self.normalized_from_hidden(self.last_hidden(nodes), nodes)
        rows = target.reshape(-1).nonzero().squeeze(-1)  # (R,) known-target rows of the flattened batch
        flat = nodes.reshape(-1, nodes.shape[-1])[rows]  # (R, F)
        inv_high = self.inv_high.expand(*nodes.shape[:-2], *self.inv_high.shape).reshape(-1, nodes.shape[-1])
        out = self.net(flat * inv_high[rows]).squeeze(-1) * target.reshape(-1)[rows]
        return target.new_zeros(target.numel()).index_copy(0, rows, out).view(target.shape)

    def last_hidden(self, nodes: th.Tensor) -> th.Tensor:
        """The MLP's last hidden layer on every node's normalized row: ``(B, N, F) -> (B, N, w)``.

        :meth:`forward_normalized` on a small batch is :meth:`normalized_from_hidden` of this. The
        two halves are apart because the output layer (one unit) runs as a matrix-vector product,
        whose rounding a team's pass over stacked parameters (:mod:`sb3_pm.agents.team_forward`)
        keeps only by running it estimator by estimator.
        """
        x = nodes * self.inv_high
        for layer in islice(self.net, len(self.net) - 1):  # Sequential.forward's loop, less the output
            x = layer(x)
        return x

    def normalized_from_hidden(self, hidden: th.Tensor, nodes: th.Tensor) -> th.Tensor:
        """``û / u_max`` before clamping from :meth:`last_hidden`'s ``(B, N, w)`` and the maps ``nodes``
        ``(B, N, F)`` (only known targets are predicted): ``(B, N)``."""
        return self.net[-1](hidden).squeeze(-1) * nodes[..., TARGET]

    def scaled(self, normalized: th.Tensor) -> th.Tensor:
        """``û`` in units of ``u`` from ``û / u_max`` ``(B, N)``, clamped to ``[0, u_max]``."""
        return normalized.clamp(0.0, 1.0) * self.u_max

    def forward(self, nodes: th.Tensor) -> th.Tensor:
        return self.scaled(self.forward_normalized(nodes))

    def loss(self, previous: th.Tensor, current: th.Tensor) -> th.Tensor:
        """MSE (in ``u / u_max`` units) between ``û(M_{k-1})`` and the u channel of ``M_k``.

        :param previous: maps ``M_{k-1}``, ``(B, N, F)``.
        :param current: maps ``M_k``, ``(B, N, F)``.
        """
        return ((self.forward_normalized(previous) - current[..., U] / self.u_max) ** 2).mean()


def transition_pairs(
    nodes: np.ndarray,
    episode_starts: np.ndarray,
    last_nodes: np.ndarray | None = None,
    last_episode_starts: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Consecutive map pairs ``(M_{k-1}, M_k)`` of one rollout, never across an episode boundary.

    Rows ``t-1`` and ``t`` of the same env form a pair unless ``episode_starts[t]`` is set (row
    ``t`` is then the first map of a new episode). ``last_nodes`` (the observation after the last
    row, SB3's ``_last_obs``) adds one more pair per env where ``last_episode_starts`` is 0.

    :param nodes: ``(T, n_envs, N, F)`` buffer observations.
    :param episode_starts: ``(T, n_envs)``.
    :return: ``previous`` and ``current``, each ``(P, N, F)``.
    """
    if last_nodes is not None:
        if last_episode_starts is None:
            raise ValueError("last_episode_starts is required with last_nodes")
        nodes = np.concatenate((nodes, last_nodes[None]), axis=0)
        episode_starts = np.concatenate(
            (episode_starts, np.asarray(last_episode_starts, dtype=np.float32)[None])
        )
    valid = episode_starts[1:] == 0  # (T-1, n_envs)
    return nodes[:-1][valid], nodes[1:][valid]
