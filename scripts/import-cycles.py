#!/usr/bin/env python3
"""The import cycles between the modules of each crate of the workspace (docs/architecture.md):
Cargo refuses a cycle between crates, and nothing refuses one between the files of a crate.

    python3 scripts/import-cycles.py            # from the repository root

A module imports another when its code (not its comments, not its tests) names a path into it
through `crate::` or `super::`, in a `use` or inline. A cycle is a strongly connected set of
two or more modules; the crate root (lib.rs, main.rs) is left out, as every module is under
it. Prints each cycle, then their count.
"""

import glob
import os
import re
import sys

# Paths through crate:: or super::, e.g. crate::config::Rig, super::super::plan.
PATH = re.compile(r"\b((?:crate|super)(?:::(?:super|[a-z_][a-z0-9_]*))+)")
# Grouped imports, e.g. use super::{plan, flow::Context}.
GROUP = re.compile(r"\b((?:crate|super)(?:::(?:super|[a-z_][a-z0-9_]*))*)::\{([^}]*)\}")


def modules(src):
    """Module path (a::b) to its file, for every .rs file under src."""
    found = {}
    for f in glob.glob(os.path.join(src, "**", "*.rs"), recursive=True):
        parts = os.path.relpath(f, src)[:-3].split(os.sep)
        if parts[-1] in ("mod", "lib", "main"):
            parts = parts[:-1]
        found["::".join(parts)] = f
    return found


def resolve(module, path, known):
    """The module a path from `module` leads into, or None (the root, or another crate)."""
    segs = path.split("::")
    if segs[0] == "crate":
        base, segs = [], segs[1:]
    else:
        base = module.split("::") if module else []
        while segs and segs[0] == "super":
            base, segs = base[:-1], segs[1:]
    candidate = base + segs
    while candidate:
        name = "::".join(candidate)
        if name in known:
            return name
        candidate = candidate[:-1]
    return None


def code_of(path):
    text = open(path, encoding="utf-8").read()
    cut = text.find("#[cfg(test)]")
    if cut >= 0:
        text = text[:cut]
    return re.sub(r"//[^\n]*", "", text)


def graph(src):
    known = modules(src)
    edges = {m: set() for m in known if m}

    def add(module, target):
        related = target == module or target.startswith(module + "::") or module.startswith(target + "::")
        if target and module and not related:
            edges[module].add(target)

    for module, path in known.items():
        code = code_of(path)
        for p in PATH.findall(code):
            add(module, resolve(module, p, known) or "")
        for base, inner in GROUP.findall(code):
            for item in inner.split(","):
                name = item.strip().split("::")[0].split(" ")[0]
                if re.fullmatch(r"[a-z_][a-z0-9_]*", name) and name != "self":
                    add(module, resolve(module, base + "::" + name, known) or "")
    return edges


def cycles(edges):
    """Tarjan's strongly connected components of two or more modules."""
    index, low, stack, on, out = {}, {}, [], set(), []
    counter = [0]
    sys.setrecursionlimit(10000)

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in edges[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for v in edges:
        if v not in index:
            visit(v)
    return out


def main():
    sources = sorted(glob.glob("crates/*/src")) + sorted(glob.glob("drivers/*/src")) + ["src"]
    total = 0
    for src in sources:
        for component in cycles(graph(src)):
            print(f"{src}: {', '.join(component)}")
            total += 1
    print(f"{total} import cycles inside crates")


if __name__ == "__main__":
    main()
