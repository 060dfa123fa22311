"""``python -m sb3_pm.zoo <command>``: rl-zoo's ``train``, ``enjoy``, ``record_video`` and
``optimize`` with our algorithms, ids and configs, for example::

    python -m sb3_pm.zoo train --algo dcbf_ppo --env sb3_pm/PersistentMonitoring-paper50-v0 -n 2048

See :mod:`sb3_pm.zoo.rl_zoo`.
"""

import sys

from sb3_pm.errors import Sb3PmError
from sb3_pm.zoo.rl_zoo import main

if __name__ == "__main__":
    try:
        main()
    except Sb3PmError as error:  # a bad command or -conf: one line, as the sb3-pm commands say it
        print(f"python -m sb3_pm.zoo: error: {error}", file=sys.stderr)
        sys.exit(2)
