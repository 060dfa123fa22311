import json, glob, sys
import numpy as np
rows = {}
for f in sorted(glob.glob('*_s*.json')):
    d = json.load(open(f)); e = d['episodes']
    a = np.array([x['avg_uncertainty'] for x in e]); n = np.array([x['max_neglect'] for x in e])
    print(f"{f:22s} mean {a.mean():7.3f}  max ep {a.max():7.2f}  eps>40: {int((a>40).sum()):2d}/{len(a)}  worst neglect {n.max():.0f}")
