"""The layout of the product packages (issue 29): import cycles, upward imports, module sizes, lines of vfmlab/cli.

    python -m benchmarks.bench_layout [ROOT]

Imports are read with the standard library's ``ast`` (every ``import`` and ``from ... import``, at any depth);
layers: acquisition, reconstruction, identification (0) < rig_sim (1) < vfmlab (2); an import from a layer to a
higher one, or between two stage packages, is reported.
"""
import ast
import os
import sys
from collections import defaultdict
ROOT = sys.argv[1] if len(sys.argv) > 1 else os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PKGS = ["acquisition", "reconstruction", "identification", "rig_sim", "vfmlab"]
LAYER = {"acquisition": 0, "reconstruction": 0, "identification": 0, "rig_sim": 1, "vfmlab": 2}
mods = {}
for p in PKGS:
    for dp, dn, fn in os.walk(os.path.join(ROOT, p)):
        for f in fn:
            if f.endswith(".py"):
                path = os.path.join(dp, f)
                rel = os.path.relpath(path, ROOT)[:-3].replace(os.sep, ".")
                if rel.endswith(".__init__"):
                    rel = rel[:-9]
                mods[rel] = path
def resolve(name):
    while name and name not in mods:
        name = name.rpartition(".")[0]
    return name or None
graph = defaultdict(set)
for m, path in mods.items():
    tree = ast.parse(open(path).read())
    pkg = m if path.endswith("__init__.py") else m.rpartition(".")[0]
    for node in ast.walk(tree):
        targets = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = pkg.split(".")
                parts = parts[: len(parts) - node.level + 1]
                base = ".".join(parts + ([base] if base else []))
            targets = [base + "." + a.name for a in node.names] + [base]
        for t in targets:
            r = resolve(t)
            if r and r != m:
                graph[m].add(r)
                break
# cycles via Tarjan SCC
index = {}; low = {}; st = []; on = set(); sccs = []; i = [0]
sys.setrecursionlimit(10000)
def sc(v):
    index[v] = low[v] = i[0]; i[0] += 1; st.append(v); on.add(v)
    for w in graph[v]:
        if w not in index:
            sc(w); low[v] = min(low[v], low[w])
        elif w in on:
            low[v] = min(low[v], index[w])
    if low[v] == index[v]:
        comp = []
        while True:
            w = st.pop(); on.discard(w); comp.append(w)
            if w == v: break
        if len(comp) > 1: sccs.append(comp)
for v in list(mods):
    if v not in index: sc(v)
print("import cycles (SCCs):", len(sccs))
for c in sccs: print("  ", sorted(c))
up = []
for m, ts in graph.items():
    a = m.split(".")[0]
    for t in ts:
        b = t.split(".")[0]
        if a != b and (LAYER[b] > LAYER[a] or (LAYER[a] == 0 and LAYER[b] == 0 and a != b)):
            up.append((m, t))
print("upward/sideways imports:", len(up))
for u in up: print("  ", u)
big = sorted(((sum(1 for _ in open(p)), m) for m, p in mods.items()), reverse=True)
print("modules over 600:", [(n, m) for n, m in big if n > 600])
print("modules over 450:", len([1 for n, m in big if n > 450]))
cli = sum(n for n, m in big if m.startswith("vfmlab.cli"))
print("vfmlab/cli lines:", cli)
print("product lines:", sum(n for n, m in big))
