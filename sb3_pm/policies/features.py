"""Derived node features computed from one agent's mental map (option ``derived_features``).

docs/METHOD.md fixes the mental map's five raw features and leaves the network's input features open.
Two quantities that a greedy patrol rule needs are not linear in the raw map, so a small network
fed 20 episodes of experience is slow to discover them:

``projected``  ``target * min(u + age, u_max) / u_max``: what a known target's uncertainty would be
               now if nobody had served it since the agent last saw it (eq. 1 grows an unserved
               target by one per step up to the cap). An upper bound of the true value, from the
               agent's own map only; 0 for nodes not known to be targets.
``closeness``  ``1 / (1 + d)``, with ``d`` the hop distance from the agent's node in its *known*
               adjacency (0 for nodes it cannot reach through edges it has seen). It tells every node
               how far it is from the agent, which the Laplacian rows encode only implicitly.

Both are computed in torch, batched, with no learnable parameters; no communication is involved
(each row reads only its own agent's map).
"""

from __future__ import annotations

import torch as th

from sb3_pm.envs.mental_map import AGE, TARGET, U

DERIVED_FEATURES = ("projected", "closeness")


def hop_distances(adjacency: th.Tensor, start: th.Tensor) -> th.Tensor:
    """Breadth-first hop distances from one start node per map.

    One frontier-times-adjacency product per hop, so the cost is ``O(B N^2)`` per hop and the
    number of hops is the eccentricity of the start node (2-4 on the paper's graphs).

    :param adjacency: known adjacency (nonzero = edge), any dtype.
    :param start: one-hot start node (nonzero = start).
    :return: hops from the start node, ``-1`` where unreachable.

    Shapes:
        - adjacency: ``(B, N, N)``; start: ``(B, N)``
        - output: ``(B, N)`` long
    """
    edges = (adjacency != 0).float()
    reached = start != 0
    distance = th.where(reached, 0, -1).long()
    frontier = reached.float().unsqueeze(1)  # (B, 1, N)
    for hop in range(1, adjacency.shape[-1]):
        step = (th.bmm(frontier, edges).squeeze(1) > 0) & ~reached
        if not bool(step.any()):
            break
        distance = th.where(step, hop, distance)
        reached = reached | step
        frontier = step.float().unsqueeze(1)
    return distance


def derived_node_features(
    nodes: th.Tensor, adjacency: th.Tensor, position: th.Tensor, u_max: float
) -> th.Tensor:
    """``[projected, closeness]`` per node (see the module docstring), both in ``[0, 1]``.

    :param nodes: raw (unnormalized) mental-map node features, columns as in
        :data:`sb3_pm.envs.mental_map.FEATURES`.
    :param adjacency: the known adjacency.
    :param position: the agent's node, one-hot.
    :param u_max: the uncertainty cap.

    Shapes:
        - nodes: ``(B, N, 5)``; adjacency: ``(B, N, N)``; position: ``(B, N)``
        - output: ``(B, N, 2)``
    """
    projected = (nodes[..., U] + nodes[..., AGE]).clamp(max=u_max) * (nodes[..., TARGET] > 0.5) / u_max
    distance = hop_distances(adjacency, position)
    closeness = th.where(distance >= 0, 1.0 / (1.0 + distance.float()), th.zeros((), device=nodes.device))
    return th.stack((projected, closeness), dim=-1)
