"""Persistent monitoring on a graph, version 0: the PettingZoo environment, its arguments and its spaces.

``n_agents`` agents move along the edges of an undirected, connected graph. Some nodes are
targets; a target's uncertainty ``u`` grows by one each step nobody is on it and falls by one
each step somebody is (docs/METHOD.md "Dynamics", the paper's eq. 1), capped at ``u_max``. Agents see
only their own neighbourhood and never communicate.

Usage::

    from sb3_pm.envs import persistent_monitoring_v0
    env = persistent_monitoring_v0.parallel_env(graph="paper-50", n_agents=4)
    observations, infos = env.reset(seed=0)

Arguments
---------
graph (``"paper-50"``)
    A preset name (``paper-50``, ``paper-100``, ``paper-200``: the paper's published graphs;
    ``er-50``, ``er-100``, ``er-200``: seeded Erdős–Rényi draws), a ``.graphml`` path, or a
    :class:`~sb3_pm.graphs.GraphSpec`. Or a graph *family* (``"family:er"``, ``"family:FOLDER"``
    or a :class:`~sb3_pm.graphs.distributions.GraphFamily`): every reset then draws the episode's
    graph from the reset seed's generator, every mental map starts empty on it, and observations
    are padded to the family's ``max_nodes`` (padding nodes: zero features, no edges, never in the
    action mask). Needs ``observation="map"``.
n_agents (``4``)
    Team size, at most the number of nodes. Agents are named ``agent_0 ... agent_{n-1}``.
max_cycles (``500``)
    Episode length K. Episodes end by truncation after K steps, never by termination.
u_max (``100``)
    Cap on every target's uncertainty.
obs_radius (``1``)
    An agent observes the nodes within this many hops of its node (their ``u``, target flag and
    whether another agent is there) and the edges incident to nodes strictly inside that ball
    (radius 1: the edges at its own node).
initial_positions (``None``)
    A list of ``n_agents`` nodes; ``None`` draws distinct nodes uniformly from the reset seed.
    ``reset(options={"initial_positions": [...]})`` overrides it for one episode.
    ``reset(options={"new_lifetime": True})`` also forgets every map's discovered edges and the
    ``change`` reward's past episodes, as if the agents were new.
initial_uncertainty (``"zero"``)
    ``"zero"`` or ``"random"`` (uniform integers in ``[0, u_max]`` on targets, from the seed).
reward (``"paper"``)
    A preset (``"paper"``: eq. 5-8; ``"reduction"``) or a ``{term: weight}`` mapping over the
    terms ``collision``, ``momentum``, ``change``, ``reduction``, ``clearing``, ``territory`` (see
    :mod:`sb3_pm.envs.rewards`).
observation (``"map"``)
    ``"map"``: each agent's mental map (what learners and decentralized baselines use);
    ``"local"``: only this step's raw local observation.
graph_knowledge (``"discovered"``)
    ``"discovered"``: a map's adjacency gains edges as its agent observes them and keeps them for
    the environment's lifetime; ``"known"``: the whole topology is known from the start.
target_knowledge (``"discovered"``)
    ``"discovered"``: a map flags a node as a target once its agent observes it, every episode;
    ``"known"``: every map starts each episode with the true target flags (a mission that knows its
    sites). Uncertainties and ages stay what the agent itself has observed.
territory_input (``False``)
    ``True`` adds a sixth node feature to map observations: 1 on the targets of the agent's own
    territory (the split of :mod:`sb3_pm.graphs.territories`, which every agent computes alike
    from the site plan and its own index, as the ``territory`` reward and the ``territory_patrol``
    baseline do), 0 elsewhere. Since the split is computed from the graph and its targets, it
    needs ``graph_knowledge`` and ``target_knowledge`` ``"known"`` and ``observation="map"``. A
    team deployed on another graph or with another team size sees that problem's split; on a graph
    family, each episode's graph gives its own (and the ``territory`` reward is then allowed).
advice_input (``False``)
    ``True`` adds one more node feature to map observations (after ``territory_input``'s, if
    any): 1 on the node the territory rule would move to next, 0 elsewhere
    (:mod:`sb3_pm.envs.territory_rule`, the rule the ``territory_patrol`` baseline acts by). The
    rule reads only the agent's own map, the site plan and its own territory, so the advice is as
    decentralized as the map; the rule keeps its own goal from step to step whatever the agent
    did. An agent with no territory (fewer targets than agents) or a failed one gets an all-zero
    column. Same requirements as ``territory_input``.
territories (``"split"``)
    Which targets make each agent's territory, for the ``territory`` reward, ``territory_input``
    and ``advice_input`` (:mod:`sb3_pm.planning.conventions`). ``"split"``: the balanced split by
    hop distance, fixed for the graph. ``"planned"``: the groups of the centralized plan for the
    episode's start positions (every agent knows where every agent starts; no uncertainty is read),
    recomputed at each reset; targets the plan leaves out belong to nobody. ``"planned_tours"``: the
    same, and each group the plan walks as a tour is walked so by the territory rule. The planned
    conventions need one of the three options on, and the ``territory`` reward with them needs
    ``territory_input``.
illegal_action (``"raise"``)
    ``"raise"``: a move outside the reachable set raises ``ValueError`` naming the agent, its node
    and the reachable set; ``"stay"``: the agent stays and ``infos[agent]["illegal_action"]``
    records the request.
shared_map (``False``)
    ``True`` feeds every agent's mental map with the union of all agents' observations: the
    *centralized* setting (docs/METHOD.md "Baselines": centralized). Never used by decentralized teams.
failures (``None``)
    Agent failures at given steps: ``{agent name: step}``, e.g. ``{"agent_1": 250}``: the agent
    acts in steps ``1..step`` and fails after that step's move. It is then *terminated* the
    PettingZoo way (``terminations[agent] = True`` and a final observation, then it leaves
    ``env.agents``); it occupies no node, clears nothing and is seen by nobody. The survivors go on
    with what their own maps hold. ``step`` lies in ``1..max_cycles - 1``.
failure_rate (``0.0``)
    After every step, each live agent fails with this probability, drawn from the reset seed's
    generator; the last live agent never fails, so every episode runs its ``max_cycles`` steps.
    With either option the episode metrics add ``failed_agents``, ``first_failure_step`` and the
    average uncertainty before and after the first failure (:mod:`sb3_pm.envs.metrics`).
render_mode (``None``)
    ``"rgb_array"`` (a matplotlib frame), ``"human"`` (a window) or ``"ansi"`` (text).
layout (``"dense"``)
    How a map observation carries the agent's known graph: ``"dense"``, the ``adjacency``
    below; ``"edges"``, ``edge_index`` and ``edge_mask`` instead, O(N + E) per observation
    (:mod:`sb3_pm.envs.known_edges`). ``"edges"`` needs ``observation="map"`` and one graph
    (not a family).

Spaces
------
Action: ``Discrete(N)``, the destination node; legal destinations are the agent's node and its
neighbours, given by ``obs["action_mask"]``.

Observation with ``observation="map"`` (a ``Dict``):

``nodes``
    ``Box(N, 5) float32``: per node ``[u, age, target, occupied, self]`` from the mental
    map (:mod:`sb3_pm.envs.mental_map`); ``Box(N, 6)`` with ``territory_input``, whose
    sixth column flags the agent's own territory; one more column with
    ``advice_input`` flags the territory rule's next move.
``adjacency``
    ``Box(N, N) int8``: the known adjacency.
``edge_index`` and ``edge_mask`` (``layout="edges"``, in place of ``adjacency``)
    ``Box(2, E) int64``: the graph's directed edges ``[i, j]`` (both directions, sorted by ``i``
    then ``j``, the same array every step); ``Box(E,) int8``: 1 on the edges the map knows.
``position``
    ``Discrete(N)``: the agent's node.
``dwell``
    ``Box(1,) float32``: steps the agent has stayed on its node (0 on arrival).
``action_mask``
    ``Box(N,) int8``: 1 on the reachable set.

Observation with ``observation="local"``: ``position``; ``observed``, ``target``, ``occupied`` and
``action_mask`` as ``Box(N,) int8``; ``uncertainty`` as ``Box(N,) float32`` (0 where unobserved);
``edges`` as ``Box(N, N) int8``.

Rewards are per agent (see :mod:`sb3_pm.envs.rewards`). When an episode ends, every agent's info
holds ``"metrics"``: ``avg_uncertainty``, ``max_neglect``, ``collisions``, ``peak_uncertainty``,
``saturated_fraction``, ``idle_fraction`` and ``steps`` (:mod:`sb3_pm.envs.metrics`);
``env.episode_metrics()`` returns them at any time. ``env.unwrapped.uncertainty`` and
``env.unwrapped.positions`` expose the true state for tests and omniscient baselines.

Implementation
--------------
:class:`~sb3_pm.envs.persistent_monitoring.PersistentMonitoringEnv` is a PettingZoo
``ParallelEnv`` adapter around :class:`~sb3_pm.envs.core.MonitoringCore` (the dynamics),
:class:`~sb3_pm.envs.mental_map.MentalMaps` (what each agent remembers),
:mod:`sb3_pm.envs.observations`, :mod:`sb3_pm.envs.rewards` and :mod:`sb3_pm.envs.metrics`. This
module re-exports its constructors (:func:`parallel_env`, :func:`env`, :data:`raw_env`) under the
versioned name, as PettingZoo's ``*_vN`` modules do.

Version history
---------------
v0: first release.
"""

from sb3_pm.envs.persistent_monitoring import env, parallel_env, raw_env

__all__ = ["env", "parallel_env", "raw_env"]
