"""One paired table from two bench/table.py runs: method A on every seed (BASE), method B on the
seeds where it acts (ARM); on the others (acts.py: "same computation") B takes A's run, marked
"same_as". Writes OUT.json with per_run rows as table.json has them, for paired.py.

    python bench/results/rest-windows/hold-rests/merge.py BASE/table.json ARM/table.json A B OUT.json
"""
import json
import sys

base, arm = json.load(open(sys.argv[1])), json.load(open(sys.argv[2]))
a, b, out = sys.argv[3], sys.argv[4], sys.argv[5]
rows = [r for r in base["per_run"] if r["method"] == a]
ran = {(r["scene"], r["seed"]) for r in arm["per_run"] if r["method"] == b}
rows += [r for r in arm["per_run"] if r["method"] == b]
rows += [{**r, "method": b, "same_as": a} for r in base["per_run"]
         if r["method"] == a and (r["scene"], r["seed"]) not in ran]
json.dump({"settings": {"base": base["settings"], "arm": arm["settings"]}, "per_run": rows}, open(out, "w"), indent=1)
print(f"{out}: {a} on {sum(r['method'] == a for r in rows)} runs, {b} trained on {len(ran)}, "
      f"taken from {a} on {sum(r.get('same_as') == a for r in rows)}")
