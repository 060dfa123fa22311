"""``python -m sb3_pm.zoo <command>``: rl-zoo's ``train``, ``enjoy``, ``record_video`` and
``optimize`` with our algorithms, ids and configs, for example::

    python -m sb3_pm.zoo train --algo dcbf_ppo --env sb3_pm/PersistentMonitoring-paper50-v0 -n 2048

See :mod:`sb3_pm.zoo.rl_zoo`.
"""

from sb3_pm.zoo.rl_zoo import main

if __name__ == "__main__":
    main()
