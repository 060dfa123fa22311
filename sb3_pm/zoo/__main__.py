"""``python -m sb3_pm.zoo``: rl-zoo's ``train`` with our algorithms registered (``dcbf_ppo``, ...).

Takes exactly rl-zoo's ``train`` arguments, for example::

    python -m sb3_pm.zoo --algo dcbf_ppo --env sb3_pm/PersistentMonitoring-paper50-v0 \\
        -conf zoo/dcbf_ppo.yml -n 2048

See :mod:`sb3_pm.zoo.rl_zoo`.
"""

from sb3_pm.zoo.rl_zoo import main

if __name__ == "__main__":
    main()
