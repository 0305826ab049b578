#!/usr/bin/env python3
"""Include cycles between source files: reads the #include "..." lines of the .c and .h files
under the given folders (default: sim engine render plan), builds the graph at the file level
with x.c, x.h and x_internal.h as one module "x", and prints every cycle (one per strongly
connected set of modules, as a path x -> y -> ... -> x, each arrow with the file whose include
makes it). Exits 1 if there is any, 0 if none.

    tools/include_cycles.py [--root DIR] [FOLDER ...]
"""
import argparse
import os
import re
import sys

INCLUDE = re.compile(r'^\s*#\s*include\s+"([^"]+)"', re.M)


def module_of(path):
    name = os.path.splitext(os.path.basename(path))[0]
    if name.endswith('_internal'):
        name = name[: -len('_internal')]
    folder = os.path.basename(os.path.dirname(path))
    return folder + '/' + name


def read_graph(root, folders):
    files = {}  # basename -> relative path
    for folder in folders:
        d = os.path.join(root, folder)
        if not os.path.isdir(d):
            continue
        for dirpath, _, names in os.walk(d):
            for n in sorted(names):
                if n.endswith(('.c', '.h')):
                    rel = os.path.relpath(os.path.join(dirpath, n), root)
                    files.setdefault(n, rel)
    edges = {}  # module -> {module: file that includes}
    for base, rel in sorted(files.items()):
        src = module_of(rel)
        edges.setdefault(src, {})
        with open(os.path.join(root, rel), encoding='utf-8', errors='replace') as f:
            text = f.read()
        for inc in INCLUDE.findall(text):
            target = files.get(os.path.basename(inc))
            if target is None:
                continue  # generated (ns_config.h) or outside the folders
            dst = module_of(target)
            if dst != src:
                edges[src].setdefault(dst, rel)
    return edges


def strongly_connected(edges):
    index, low, stack, on, out = {}, {}, [], set(), []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(edges.get(v, {})):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    sys.setrecursionlimit(10000)
    for v in sorted(edges):
        if v not in index:
            visit(v)
    return out


def cycle_in(edges, comp):
    """A shortest cycle through the first module of comp, within comp."""
    members, start = set(comp), comp[0]
    prev, frontier = {start: None}, [start]
    while frontier:
        nxt = []
        for v in frontier:
            for w in sorted(edges.get(v, {})):
                if w not in members:
                    continue
                if w == start:
                    path = [v]
                    while prev[path[-1]] is not None:
                        path.append(prev[path[-1]])
                    return list(reversed(path)) + [start]
                if w not in prev:
                    prev[w] = v
                    nxt.append(w)
        frontier = nxt
    return comp


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--root', default=os.path.join(os.path.dirname(__file__), '..'))
    ap.add_argument('folders', nargs='*', default=['sim', 'engine', 'render', 'plan'])
    args = ap.parse_args()
    edges = read_graph(args.root, args.folders)
    comps = strongly_connected(edges)
    for comp in comps:
        path = cycle_in(edges, comp)
        steps = ['%s -> %s (%s)' % (a, b, edges[a][b]) for a, b in zip(path, path[1:])]
        print('include cycle among %s: %s' % (', '.join(comp), '; '.join(steps)))
    if not comps:
        print('no include cycles in %d modules (%s)' % (len(edges), ' '.join(args.folders)))
    return 1 if comps else 0


if __name__ == '__main__':
    sys.exit(main())
