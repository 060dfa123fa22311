import json,os,sys
R='..'
mx=lambda d:max(e['max_neglect'] for e in d['episodes'])
for g in ["cliques-6x8","tree-50","rooms-4","karate"]:
    for s in range(3):
        f=f"p4_pauto_{g}_s{s}.json"
        if not os.path.exists(f): continue
        d=json.load(open(f)); plain=json.load(open(f"{R}/held_out_prior4/p4_plain_{g}_s{s}.json")); rule=json.load(open(f"{R}/held_out_prior4/territory_patrol_{g}_s{s}.json"))
        print(g,s,"auto(planned)",round(d['mean']['avg_uncertainty'],1),"maxneg",mx(d),"| plain",round(plain['mean']['avg_uncertainty'],1),mx(plain),"| rule",round(rule['mean']['avg_uncertainty'],1),mx(rule), "B",d['config'].get('neglect_calibration',{}).get('bound'))
