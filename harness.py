"""Fast: peers cached; canal variants evaluated on the same folds."""
import os, sys, pickle, time
sys.path.insert(0, "/work/main")
os.environ.setdefault("OMP_NUM_THREADS", "1")
import numpy as np
from bench import quality as Q
from canal_core import metrics

def plan(users=None):
    only = {"rail", "lasa", "multi", "ur5e", "raw3d"}
    return Q.plan_groups(only, False, 3, users)

def peers_cache(users=None):
    key = "all" if users is None else "-".join(map(str, users))
    path = f"/tmp/m6/peers_{key}.pkl"
    if os.path.exists(path):
        return pickle.load(open(path, "rb"))
    out = {}
    for group, sets, unit in plan(users):
        recs = Q.evaluate(group, sets, Q.PEERS)
        out[group] = recs
    pickle.dump(out, open(path, "wb"))
    return out

def run(method, users=None, groups=None, label="canal"):
    peers = peers_cache(users)
    fit, rep = method
    res = {}
    for group, sets, unit in plan(users):
        if groups and not any(g.lower() in group.lower() for g in groups):
            continue
        recs = Q.evaluate(group, sets, {label: (fit, rep)})
        pr = peers[group]
        peer, pv = Q.best_peer(pr)
        mine = Q._median(recs, "dtw")
        theirs = {(r["set"], r["fold"]): r["dtw"] for r in pr if r["method"] == peer and "dtw" in r}
        closer = sum(r["dtw"] < theirs[(r["set"], r["fold"])] for r in recs if "dtw" in r)
        fails = sum("error" in r for r in recs)
        res[group] = (mine / pv, closer, len(recs), fails, peer)
    return res

def show(res, ref=None):
    for g, (r, c, n, f, p) in res.items():
        extra = f"  (ref {ref[g][0]:.3f} d={r-ref[g][0]:+.3f})" if ref and g in ref else ""
        print(f"{g:16s} {r:.3f}  closer {c}/{n}  fail {f}  vs {p}{extra}")
    rs = [v[0] for v in res.values()]
    print(f"<=1: {sum(r<=1 for r in rs)}/{len(rs)}  <=0.95: {sum(r<=0.95 for r in rs)}/{len(rs)}  geo {np.exp(np.mean(np.log(rs))):.4f}")
