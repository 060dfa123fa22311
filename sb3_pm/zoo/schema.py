"""The schema of a team config entry: every key a config may set, its type, default, range and meaning.

This module is the single list of keys. :func:`sb3_pm.zoo.config.load_config` checks every key of
an entry (and of an experiment variant's settings, merged into the entry) against it
(:mod:`sb3_pm.zoo.checks`), and ``docs/CONFIG.md``'s key tables are generated from it
(:mod:`sb3_pm.zoo.schema_doc`).

The defaults written here are documentation: the loader never fills in an algorithm, policy or env
default (the learner, the policy and the environment apply their own, which tests compare with
these), only the team defaults of :data:`TEAM`. The module imports nothing heavy (no torch).
"""

from __future__ import annotations

from typing import Any

from sb3_pm.zoo.schema_key import KINDS, Key, Section

#: The tag of the last release with the research switches below (docs/RESEARCH_SNAPSHOT.md).
RESEARCH_TAG = "v0.1.0-research"
#: Research switches that measurement rejected and the package no longer has, as a config writes
#: them (an algorithm or ``policy_kwargs`` key, ``reward: <term>`` in ``env_kwargs``, or
#: ``laplacian: <value>``), with where they were set. :func:`sb3_pm.zoo.checks.check_removed`
#: refuses them.
REMOVED_KEYS: dict[str, str] = {
    "extra_attention": "policy_kwargs",
    "derived_features": "policy_kwargs",
    "estimator_target": "policy_kwargs",
    "actor_nodes": "policy_kwargs",
    "gat_sparse_kernel": "policy_kwargs",
    "laplacian: eigen": "policy_kwargs",
    "ent_coef_final": "dcbf_ppo",
    "estimator_update_at": "dcbf_ppo",
    "reward: crowding": "env_kwargs",
    "reward: urgency": "env_kwargs",
    "reward: neglect": "env_kwargs",
}

_NUMBER = {"low": 0.0, "low_open": True}  # positive
_UNIT = {"low": 0.0, "low_open": True, "high": 1.0}  # (0, 1]

TEAM = Section('team', 'Team keys', 'entry', keys=(
    Key('n_timesteps', 'int', 50_000, low=1,
        help='steps per learner, as SB3 counts them (a 4-agent team at 50,000 takes 200,000 agent-steps); '
        '`5e4` is accepted'),
    Key('n_envs', 'int', 1, low=1,
        help='env copies each learner collects from (the same for every agent)'),
    Key('n_agents', 'int', 4, low=1,
        help='team size; agents are `agent_0 ... agent_{n-1}`'),
    Key('algo', 'str', 'dcbf_ppo',
        choices=('dcbf_ppo', 'maskable_ppo', 'ppo'),
        default_text='`dcbf_ppo` (`maskable_ppo` where it cannot be imported)',
        help="the learner: `dcbf_ppo` is the paper's method"),
    Key('policy', 'str', None, default_text="the algorithm's default",
        help='the policy: `DCBFPolicy` for `dcbf_ppo`, `MultiInputPolicy` otherwise'),
    Key('env_kwargs', 'mapping', {},
        help='environment arguments, see [below](#env_kwargs)'),
    Key('agents', 'mapping', {},
        help='per-agent overrides, see [below](#per-agent-overrides)'),
    Key('env', 'str', None, nullable=True, expects='a graph or family name',
        help='the graph or graph family `sb3-pm train` trains on without `--env` (`family:er`: a new graph'
        ' every episode); `--env` wins'),
    Key('deploy_temperature', 'deploy_temperature', None, low=0.0, low_open=True, nullable=True,
        help='how the trained team acts: `null` by its most likely allowed node, `T` by sampling '
        '`softmax(logits / T)`; see [Deployment rules](#deployment-rules)'),
    Key('deploy_filter', 'deploy_filter', None, nullable=True,
        help='the DCBF rules the trained team acts under, `{neglect_bound: B \\| auto, '
        'neglect_scope: S, leave_cleared: true, pass_held: true, keep_moving: true, '
        'visit_deadline: D \\| auto}` (the scope is optional; the bound may be left out where a switch '
        'or the deadline is on); `null`: the filter it trained '
        'under; see [Deployment rules](#deployment-rules)'),
    Key('learning_rate_spread', 'float', 1.0, low=1.0,
        help="the fastest learner's learning rate over the slowest's; `1`: every learner the same; see "
        '[Staggered learning rates](#staggered-learning-rates)'),
))

ALGORITHM = Section('algorithm', 'Algorithm keys', 'entry', keys=(
    Key('learning_rate', 'schedule', 0.0003, low=0.0, low_open=True,
        help="the optimizer's step size; `lin_<x>` decays linearly from x to 0"),
    Key('n_steps', 'int', 2048, low=2,
        help='steps per env copy in each rollout (every learner of a team the same)'),
    Key('batch_size', 'int', 64, low=1,
        help='minibatch size; at most `n_steps × n_envs`'),
    Key('n_epochs', 'int', 10, low=1,
        help='passes over each rollout'),
    Key('gamma', 'float', 0.99, low=0.0, high=1.0, low_open=True,
        help='discount factor'),
    Key('gae_lambda', 'float', 0.95, low=0.0, high=1.0, low_open=True,
        help="GAE's bias-variance trade-off λ"),
    Key('clip_range', 'schedule', 0.2, low=0.0, low_open=True,
        help="PPO's policy clipping ε (or `lin_<x>`)"),
    Key('clip_range_vf', 'schedule', None, low=0.0, low_open=True, nullable=True,
        help='value clipping (or `lin_<x>`); `null`: none'),
    Key('normalize_advantage', 'bool', True,
        help='normalise the advantages of each minibatch'),
    Key('ent_coef', 'float', 0.0, low=0.0,
        help='entropy bonus coefficient'),
    Key('vf_coef', 'float', 0.5, low=0.0,
        help='value loss coefficient'),
    Key('max_grad_norm', 'float', 0.5, low=0.0, low_open=True,
        help='gradient clipping norm'),
    Key('use_sde', 'bool', False, algos=('ppo',),
        help='generalised state-dependent exploration (`ppo` only)'),
    Key('sde_sample_freq', 'int', -1, algos=('ppo',),
        help='gSDE noise resampling period (`ppo` only)'),
    Key('rollout_buffer_class', 'any', None, nullable=True,
        help="SB3's rollout buffer class (a class, not a name: for Python callers)"),
    Key('rollout_buffer_kwargs', 'mapping', None, nullable=True,
        help='arguments of the rollout buffer'),
    Key('target_kl', 'float', None, low=0.0, low_open=True, nullable=True,
        help="stop an update's epochs early past this KL divergence; `null`: never"),
    Key('advice_imitation', 'float', 0.0, low=0.0, algos=('dcbf_ppo',),
        help="weight of the passes after each update that teach the actor the node `env_kwargs.advice_input` "
        'flags; `0`: none; see [below](#advice-prior)'),
    Key('stats_window_size', 'int', 100, low=1,
        help='episodes averaged in the logged statistics'),
    Key('policy_kwargs', 'mapping', None, nullable=True,
        help="the policy's arguments, see [below](#policy_kwargs)"),
))

ENCODER = Section('encoder', '`DCBFPolicy`: the GAT encoder', 'policy_kwargs', policy='DCBFPolicy', keys=(
    Key('laplacian', 'str', 'rows', choices=('rows', 'none'),
        help='graph Laplacian features'),
    Key('gat_heads', 'int', 4, low=1,
        help='heads per GAT layer'),
    Key('hidden_dim', 'int', 32, low=1,
        help='node embedding size h'),
    Key('gat_layers', 'int', 2, low=1,
        help='number of multi-head GAT layers'),
    Key('gat_backend', 'str', 'auto', choices=('auto', 'dense', 'sparse'),
        help='the GAT kernel'),
    Key('features_extractor_class', 'str', 'GATFeaturesExtractor',
        help='the encoder class, by registry name (`GATFeaturesExtractor`, ...)'),
    Key('features_extractor_kwargs', 'mapping', None, nullable=True,
        help='extra encoder arguments (the explicit keys above win)'),
))

ESTIMATOR = Section(
    'estimator', '`DCBFPolicy`: the state estimator', 'policy_kwargs', policy='DCBFPolicy', keys=(
    Key('use_estimator', 'bool', True,
        help="build the estimator (off: no `û` input to the heads; the filter uses the map's last observed"
        ' `u`)'),
    Key('estimator_hidden', 'list', [64, 64],
        help='hidden sizes of the estimator MLP'),
    Key('estimator_lr', 'float', 0.001, low=0.0, low_open=True,
        help='Adam learning rate of the estimator'),
    Key('estimator_epochs', 'int', 5, low=0,
        help='passes over each rollout when fitting the estimator'),
    Key('estimator_batch_size', 'int', 256, low=1,
        help='minibatch size when fitting the estimator'),
))

ACTOR_CRITIC = Section('actor_critic', 'Actor and critic (every policy)', 'policy_kwargs', keys=(
    Key('net_arch', 'any', None, nullable=True, default_text='`{pi: [64, 64], vf: [64, 64]}`',
        help='hidden sizes of the actor and critic heads: `{pi: [...], vf: [...]}` or one list for both'),
    Key('activation_fn', 'str', 'Tanh',
        help='activation of the heads, by registry name (`ReLU`, `Tanh`, `ELU`, ...)'),
    Key('ortho_init', 'bool', True,
        help='orthogonal initialisation of the heads'),
    Key('optimizer_class', 'str', 'Adam',
        help='the actor-critic optimizer, by registry name (`Adam`, `AdamW`, `RMSprop`, `SGD`)'),
    Key('optimizer_kwargs', 'mapping', None, nullable=True,
        help='arguments of the optimizer'),
    Key('share_features_extractor', 'bool', True,
        help='actor and critic share the encoder'),
    Key('normalize_images', 'bool', True,
        help="SB3's image normalisation (no image inputs here)"),
    Key('advice_prior', 'float', 0.0,
        help='`DCBFPolicy` only: a fixed number added to the logit of the node `env_kwargs.advice_input` '
        'flags; see [below](#advice-prior)'),
))

#: The filter's on/off rules (9 to 11), each a bool key.
_FILTER_SWITCHES = {
    'leave_cleared': 'rule 9: an agent on a target it observes cleared (u = 0) does not stay there',
    'pass_held': 'rule 10: an agent off targets whose advised next node holds another agent waits a '
    'step, then takes it; needs `advice_input`',
    'keep_moving': 'rule 11: an agent off targets whose advised next node is another, free node does '
    'not stay; needs `advice_input`',
}

DCBF = Section(
    'dcbf', '`DCBFPolicy`: the DCBF filter (`sb3_pm.policies.dcbf.DCBFConfig`)', 'policy_kwargs',
    policy='DCBFPolicy', keys=(
    Key('use_dcbf', 'bool', True,
        help='apply the DCBF safety filter (off: the mask is the reachable set)'),
    Key('dcbf_barrier', 'bool', True,
        help='rules 2–4, the barrier on û (`DCBFConfig.barrier`); `false` keeps feasibility, the freeze '
        'and rule 6 (not in the paper; docs/RESULTS.md)'),
    Key('freeze_steps', 'int', 10, low=0,
        help='rule 5, steps an agent dwells on a target (0 disables the freeze)'),
    Key('avoid_collisions', 'bool', False,
        help='rule 6: do not move onto an occupied node'),
    Key('eta', 'float', 0.1, low=0.0, high=1.0,
        help='the margin η of rule 2'),
    Key('gamma_threshold', 'float', 0.0,
        help='rule 7, the activation threshold γ, in units of u'),
    Key('neglect_bound', 'float', None, low=1.0, nullable=True,
        help='rule 8, the neglect bound B (`sb3_pm/policies/neglect_bound.py`); needs `use_dcbf`; usually '
        'set after training by `deploy_filter`'),
    Key('neglect_scope', 'str', 'known', choices=('known', 'unserved', 'territory'),
        help="the targets rule 8 covers (`territory`: the agent's own)"),
    Key('neglect_territory', 'list', [], default_text='`[]`',
        help="the agent's own targets, for `neglect_scope: territory` (filled in by `deploy_filter`)"),
    *(Key(switch, 'bool', False, help=f'{rule}; usually set after training by `deploy_filter`')
      for switch, rule in _FILTER_SWITCHES.items()),
))

ENV = Section('env', 'Environment keys (`env_kwargs`)', 'env_kwargs', keys=(
    Key('max_cycles', 'int', 500, low=1,
        help='episode length K; episodes end by truncation, never termination'),
    Key('u_max', 'float', 100, low=0.0, low_open=True,
        help="cap on every target's uncertainty"),
    Key('obs_radius', 'int', 1, low=0,
        help='an agent observes the nodes within this many hops'),
    Key('initial_positions', 'list', None, nullable=True,
        help='a list of `n_agents` nodes; `null` draws distinct nodes from the reset seed'),
    Key('initial_uncertainty', 'str', 'zero', choices=('zero', 'random'),
        help='`random`: uniform in `[0, u_max]` on targets'),
    Key('reward', 'reward', 'paper',
        help='a preset or `{term: weight}`, see [Reward terms](#reward-terms)'),
    Key('observation', 'str', 'map', choices=('map', 'local'),
        help='`map` (the mental map; learners need it) or `local`'),
    Key('graph_knowledge', 'str', 'discovered', choices=('discovered', 'known'),
        help='`discovered`: the map learns edges as it sees them; `known`: the road network from the start'),
    Key('target_knowledge', 'str', 'discovered', choices=('discovered', 'known'),
        help='`discovered`: a node is flagged a target once observed, every episode; `known`: every map '
        'starts with the true flags'),
    Key('territory_input', 'bool', False,
        help="a sixth node feature: 1 on the targets of the agent's own territory; needs both knowledge "
        'keys `known`'),
    Key('advice_input', 'bool', False,
        help='one more node feature: 1 on the node the territory rule (`sb3_pm/envs/territory_rule.py`) '
        'moves to next; needs both knowledge keys `known`'),
    Key('territories', 'str', 'split', choices=('split', 'planned', 'planned_tours'),
        help="each agent's territory: `split` (balanced by hop distance, fixed per graph), `planned` (the "
        "plan's groups for the episode's starts, see docs/PLANNING.md) or `planned_tours` (the same, "
        "with the groups the plan walks as tours walked so by the territory rule)"),
    Key('illegal_action', 'str', 'raise', choices=('raise', 'stay'),
        help='what an unmasked illegal move does (`stay` is the default for `algo: ppo`)'),
    Key('shared_map', 'bool', False,
        help="the centralized setting: every map gets the team's union of observations"),
    Key('failures', 'mapping', None, nullable=True,
        help="evaluation only: `{agent: step}`, the agent fails after that step's move"),
    Key('failure_rate', 'float', 0.0, low=0.0, high=1.0,
        help='evaluation only: each live agent fails after every step with this probability (seeded; the '
        'last one never fails)'),
    Key('render_mode', 'str', None, choices=('rgb_array', 'human', 'ansi'), nullable=True,
        help='how the env renders'),
    Key('layout', 'str', 'dense', choices=('dense', 'edges'),
        help="a map observation's known graph: `dense`, an `(N, N)` adjacency; `edges`, the graph's edge "
        'list and a known-edge mask, O(N + E) (one graph, `observation: map`; see docs/environment.md)'),
))

REWARD = Section('reward', 'Reward terms (`env_kwargs.reward`)', 'reward', keys=(
    Key('collision', 'float', None,
        help="-3 when another agent shares the agent's node (eq. 6)"),
    Key('momentum', 'float', None,
        help='a counter, +1 on arriving where u > 0, else -1, reset each episode (eq. 8)'),
    Key('change', 'float', None,
        help="Ū − U_i at the episode's last step, against the agent's previous 10 episodes (eq. 7)"),
    Key('reduction', 'float', None,
        help="the agent's marginal effect on total target uncertainty this step"),
    Key('clearing', 'float', None,
        help='1 on a target with u > 0 where the agent is alone, else 0'),
    Key('territory', 'float', None,
        help="what `clearing` pays, on the targets of the agent's own territory only"),
))

#: ``reward: <preset>`` names these weights (``sb3_pm.envs.rewards.REWARD_PRESETS``).
REWARD_PRESETS = ("paper", "reduction")

EXPERIMENT = Section('experiment', 'Experiment keys (`zoo/experiments/*.yml`)', 'experiment', keys=(
    Key('name', 'str', None, default_text="the file's stem", help='the experiment, in reports'),
    Key('description', 'str', None, nullable=True, help='what the experiment measures (not used)'),
    Key('graphs', 'list', None, help='preset names, graph families or `.graphml` paths (required)'),
    Key('seeds', 'list', None, help='training seeds; the evaluation seeds derive from them (required)'),
    Key('episodes', 'int', 10, low=1, help='evaluation episodes per cell'),
    Key('max_cycles', 'int', 500, low=1, help="every cell's episode length, training and evaluation"),
    Key('n_agents', 'int', 4, low=1, help='team size of every cell'),
    Key('config', 'str', None, nullable=True,
        help='the team config of the learned variants, relative to the file (required with one)'),
    Key('timesteps', 'int', None, low=1, nullable=True,
        help="steps per learner; `null`: the config's `n_timesteps`"),
    Key('env_kwargs', 'mapping', {}, help="env keys of every cell, merged into the config's"),
    Key('eval_env_kwargs', 'mapping', {},
        help="env keys of every cell's evaluation, never of training (`failures: {agent_1: 250}`)"),
    Key('hyperparams', 'mapping', {},
        help="team and algorithm keys merged into every learned variant's config entry"),
    Key('quick', 'mapping', {}, help="`--quick`'s overrides of the keys above, for smoke tests"),
    Key('variants', 'mapping', None, help='the rows of the tables: name -> variant keys (required)'),
))

VARIANT = Section('variant', 'Variant keys (`variants: {name: ...}`)', 'variant', keys=(
    Key('kind', 'str', 'independent', choices=('independent', 'centralized', 'baseline'),
        help='a decentralized team, one shared network and map, or a hand-written baseline'),
    Key('label', 'str', None, default_text='the variant\'s name', help='the name in tables'),
    Key('policy', 'str', None, nullable=True, help='a baseline: its name (required)'),
    Key('config', 'str', None, nullable=True,
        help="a learned variant: another team config to start from, relative to the file"),
    Key('hyperparams', 'mapping', {}, help="team and algorithm keys merged over the experiment's"),
    Key('policy_kwargs', 'mapping', {}, help="policy keys merged over the config's, key by key"),
    Key('env_kwargs', 'mapping', {},
        help="env keys merged over the experiment's (a baseline: its evaluation env's)"),
    Key('train', 'bool', True, help='`false`: evaluate the team as built, untrained (a control)'),
    Key('train_env', 'str', None, nullable=True,
        help='independent: train one team per seed on this graph or family, deploy it on every graph'),
    Key('train_agents', 'int', None, low=1, nullable=True,
        help="with `train_env`: the team size it trains with (deployed with the experiment's `n_agents`)"),
    Key('timesteps', 'int', None, low=1, nullable=True, help="this variant's budget per learner"),
    Key('agents', 'mapping', {}, help="independent: per-agent overrides, replacing the config's `agents`"),
))

#: The experiment file's sections (:mod:`sb3_pm.experiments.spec` reads them).
EXPERIMENT_SECTIONS: tuple[Section, ...] = (EXPERIMENT, VARIANT)

SECTIONS: tuple[Section, ...] = (TEAM, ALGORITHM, ENCODER, ESTIMATOR, ACTOR_CRITIC, DCBF, ENV, REWARD)
#: Every key by section name and key name.
KEYS: dict[str, dict[str, Key]] = {
    section.name: {key.name: key for key in section.keys} for section in SECTIONS + EXPERIMENT_SECTIONS
}
#: The team's own keys (never passed to a learner, never overridden per agent).
TEAM_KEYS: tuple[str, ...] = TEAM.names()
#: The team keys an experiment records for each learned variant as its config resolves them (so a
#: folder never resumes into cells trained or evaluated another way), with the value that means
#: "not set" (left out of the record).
RECORDED_TEAM_KEYS: dict[str, Any] = {
    "deploy_temperature": None,
    "learning_rate_spread": 1.0,
    "deploy_filter": None,
}
#: ``policy_kwargs`` keys that only ``DCBFPolicy`` takes.
DCBF_POLICY_ONLY = frozenset(ENCODER.names()[:5] + ESTIMATOR.names() + DCBF.names() + ("advice_prior",))


#: Every ``policy_kwargs`` key (``DCBFPolicy`` takes them all).
POLICY_KEYS: dict[str, Key] = {**KEYS["encoder"], **KEYS["estimator"], **KEYS["actor_critic"], **KEYS["dcbf"]}


def policy_keys(policy: str) -> dict[str, Key]:
    """The ``policy_kwargs`` keys ``policy`` takes (``DCBFPolicy``: all of them; SB3's policies:
    the actor-critic and encoder-class keys)."""
    if policy == "DCBFPolicy":
        return POLICY_KEYS
    return {name: key for name, key in POLICY_KEYS.items() if name not in DCBF_POLICY_ONLY}


def algorithm_keys(algo: str) -> dict[str, Key]:
    """The algorithm keys ``algo`` takes."""
    return {name: key for name, key in KEYS["algorithm"].items() if not key.algos or algo in key.algos}


__all__ = [
    "EXPERIMENT_SECTIONS",
    "KINDS",
    "KEYS",
    "POLICY_KEYS",
    "RECORDED_TEAM_KEYS",
    "REMOVED_KEYS",
    "RESEARCH_TAG",
    "SECTIONS",
    "TEAM_KEYS",
    "Key",
    "Section",
    "algorithm_keys",
    "policy_keys",
]
