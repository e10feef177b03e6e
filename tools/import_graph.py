"""The file-level import graph of src/ (issue 59's figures).

A file imports another when its code (not comments, not its inline unit
tests, not a sibling tests.rs) names a path (crate::a::b, super::x,
self::x) that resolves to that file's module. Prints the number of files
and edges and every strongly connected component of more than one file
(a set of files that import each other round a cycle).

    python3 tools/import_graph.py [src]           the whole crate
    ONLY=server python3 tools/import_graph.py     the files under src/server/ only
    EDGES=1 ONLY=store python3 tools/import_graph.py   with each file's imports

toy_engine.rs (unit tests only, it walks every layer) is left out."""
import os, re, sys
root = sys.argv[1] if len(sys.argv) > 1 else 'src'
mods = {}  # module path tuple -> file
for d, _, fs in os.walk(root):
    for f in fs:
        if not f.endswith('.rs'): continue
        p = os.path.join(d, f)
        rel = os.path.relpath(p, root)[:-3].split(os.sep)
        if rel[-1] in ('mod',): rel = rel[:-1]
        if rel == ['main']: continue  # a crate of its own (the binary)
        if rel == ['lib']: rel = []
        if rel and rel[-1] == 'tests': continue  # unit tests
        if rel == ['toy_engine']: continue
        mods[tuple(rel)] = p
def module_of(p):
    rel = os.path.relpath(p, root)[:-3].split(os.sep)
    if rel[-1] == 'mod': rel = rel[:-1]
    if rel in (['lib'], ['main']): rel = []
    return tuple(rel)
def resolve(path):
    # longest prefix that is a module
    for n in range(len(path), 0, -1):
        if tuple(path[:n]) in mods: return tuple(path[:n])
    return None
edges = {}
tok = re.compile(r'\b(crate|super|self)((?:::[A-Za-z_][A-Za-z0-9_]*)+)')
grp = re.compile(r'\b(crate|super|self)((?:::[A-Za-z_][A-Za-z0-9_]*)*)::\{([^;]*?)\}', re.S)
for m, p in mods.items():
    text = open(p).read()
    # strip tests module inline
    i = text.find('#[cfg(test)]\nmod tests {')
    if i >= 0: text = text[:i]
    text = re.sub(r'(?<![:"])//[^\n]*', '', text)
    # `mod x;` declared here: a path starting `x::` is `self::x::`.
    children = set(re.findall(r'^\s*(?:pub(?:\([^)]*\))?\s+)?mod\s+([a-z_][a-z0-9_]*)\s*;', text, re.M))
    text = re.sub(r'(?<![A-Za-z0-9_:])(' + '|'.join(sorted(children)) + r')::', r'self::\1::', text) if children else text
    targets = set()
    def base(kind):
        if kind == 'crate': return []
        here = list(m)
        if kind == 'self': return here
        # super
        return here[:-1]
    def add(kind, segs):
        b = base(kind)
        while segs and segs[0] == 'super':
            b = b[:-1]; segs = segs[1:]
        t = resolve(b + segs)
        if t is not None and t != m and t != ():
            targets.add(t)
    for g in grp.finditer(text):
        kind, pre, inner = g.group(1), [s for s in g.group(2).split('::') if s], g.group(3)
        for item in re.split(r',', re.sub(r'\{[^{}]*\}', lambda x: x.group(0).replace(',', ';'), inner)):
            item = item.strip()
            if not item: continue
            segs = [s for s in re.split(r'::', item.split(' as ')[0].split('{')[0]) if s and s != '*' and s.strip()]
            segs = [s.strip() for s in segs]
            add(kind, pre + segs)
    for t in tok.finditer(text):
        add(t.group(1), [s for s in t.group(2).split('::') if s])
    edges[m] = targets
# Tarjan
index = {}; low = {}; stack = []; on = set(); sccs = []; c = [0]
sys.setrecursionlimit(10000)
def strong(v):
    index[v] = low[v] = c[0]; c[0] += 1; stack.append(v); on.add(v)
    for w in edges.get(v, ()):
        if w not in index: strong(w); low[v] = min(low[v], low[w])
        elif w in on: low[v] = min(low[v], index[w])
    if low[v] == index[v]:
        comp = []
        while True:
            w = stack.pop(); on.discard(w); comp.append(w)
            if w == v: break
        sccs.append(comp)
for v in list(edges):
    if v not in index: strong(v)

import os as _os
only = _os.environ.get('ONLY')
if only:
    keep = {m for m in edges if m and (m[0] == only or '/'.join(m).startswith(only.rstrip('/') + '/'))}
    edges = {m: {t for t in ts if t in keep} for m, ts in edges.items() if m in keep}
    index.clear(); low.clear(); stack.clear(); on.clear(); sccs.clear(); c[0] = 0
    for v in list(edges):
        if v not in index: strong(v)
big = sorted([s for s in sccs if len(s) > 1], key=len, reverse=True)

if _os.environ.get('EDGES'):
    for m in sorted(edges):
        print('/'.join(m), '->', ' '.join(sorted('/'.join(t) for t in edges[m])))
print(f"files {len(mods)}, import edges {sum(len(t) for t in edges.values())}, cycles (SCCs > 1 file) {len(big)}")
for s in big:
    print(len(s), ' '.join(sorted('/'.join(x) for x in s)))
