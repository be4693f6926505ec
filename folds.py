import harness as H, sys, numpy as np
from bench import quality as Q
import canal_core
g = sys.argv[1]
peers = H.peers_cache()
for group, sets, unit in H.plan():
    if group != g: continue
    recs = Q.evaluate(group, sets, {"c": Q.routes_method()})
    pr = peers[group]; peer, pv = Q.best_peer(pr)
    th = {(r["set"], r["fold"]): r for r in pr if r["method"] == peer}
    for r in recs:
        demos = sets[r["set"]]
        train = [d.positions for j, d in enumerate(demos) if j != r["fold"]]
        rt = canal_core.routes.fit_routes(train, n_samples=200)
        idx, rep = rt.reproduce_detailed(demos[r["fold"]].positions[0])
        print(r["set"][:18], r["fold"], r.get("person"), f"canal {r['dtw']:.4g} {peer} {th[(r['set'], r['fold'])]['dtw']:.4g}", "routes", len(rt.canals) if hasattr(rt,'canals') else '?', "took", idx, "in", r["start in"])
