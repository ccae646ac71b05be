"""Two bake directories compared: every EXR channel and every number of bake.json (the timings left out).

    python benchmarks/bake_diff.py BASE_DIR NEW_DIR

Per EXR channel: max |a - b| / max |a|, the largest relative change where |a| > 1e-3 max |a|, and the share of
texels that changed; then how many bake.json values differ and their largest relative difference
(docs/notes/bake.md, "Bake time, twenty-second session": a speed change must leave these at 0 or float rounding).
"""
import json, sys, glob, os
import numpy as np
import OpenEXR
a, b = sys.argv[1], sys.argv[2]
worst = 0.0
for f in sorted(glob.glob(a + "/*.exr")):
    n = os.path.basename(f)
    with OpenEXR.File(f) as fa, OpenEXR.File(os.path.join(b, n)) as fb:
        for ch in fa.channels():
            x = np.asarray(fa.channels()[ch].pixels, np.float64); y = np.asarray(fb.channels()[ch].pixels, np.float64)
            m = np.max(np.abs(x)) or 1.0
            d = np.max(np.abs(x - y)) / m
            big = np.abs(x) > 1e-3 * m
            rel = np.max(np.abs(x - y)[big] / np.abs(x[big])) if big.any() else 0.0
            frac = np.mean(x != y)
            worst = max(worst, d)
            print(f"{n:8s} {ch:6s} max|d|/max|a| {d:.2e}  max rel (|a|>1e-3 max) {rel:.2e}  changed {100*frac:.2f} %")
def nums(o, path=""):
    if isinstance(o, dict):
        for k, v in o.items():
            if k in ("timings",): continue
            yield from nums(v, path + "/" + k)
    elif isinstance(o, list):
        for i, v in enumerate(o): yield from nums(v, f"{path}[{i}]")
    elif isinstance(o, (int, float)) and not isinstance(o, bool):
        yield path, float(o)
    else:
        yield path, o
ja = dict(nums(json.load(open(a + "/bake.json")))); jb = dict(nums(json.load(open(b + "/bake.json"))))
diff = [(k, ja[k], jb.get(k)) for k in ja if ja[k] != jb.get(k) and "timings" not in k and "out" not in k]
rel = [abs(x - y) / max(abs(x), 1e-30) for k, x, y in diff if isinstance(x, float) and isinstance(y, float)]
print(f"bake.json: {len(diff)} values differ; max relative {max(rel) if rel else 0:.2e}; non-numeric diffs: {[d for d in diff if not isinstance(d[1], float)][:5]}")
print(f"worst EXR max|d|/max|a|: {worst:.2e}")
