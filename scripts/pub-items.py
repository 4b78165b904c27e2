#!/usr/bin/env python3
"""The public items of each library crate of the workspace that no other crate names
(docs/architecture.md): candidates for `pub(crate)`.

    python3 scripts/pub-items.py            # from the repository root
    python3 scripts/pub-items.py --list     # and each item

An item is a `pub fn`, `pub struct`, `pub enum`, `pub trait`, `pub type`, `pub const` or
`pub static` in a crate's `src/` (its tests left out). It counts as used elsewhere when its
name appears, as a whole word, in the code of another crate, the binary (`src/`), the
integration tests (`tests/`) or the fuzz targets (`fuzz/`). By name alone, so an item another
crate's same-named item hides is counted as used: the figure is a lower bound.
"""

import glob
import importlib.util
import os
import re
import sys

ITEM = re.compile(
    r"^\s*pub\s+(?:unsafe\s+)?(?:const\s+)?(?:async\s+)?"
    r"(fn|struct|enum|trait|type|const|static)\s+([A-Za-z_][A-Za-z0-9_]*)",
    re.M,
)


def load_sibling(name):
    """A script beside this one, as a module (its name has a hyphen)."""
    path = os.path.join(os.path.dirname(os.path.abspath(__file__)), name)
    spec = importlib.util.spec_from_file_location(name.replace("-", "_")[:-3], path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# A file's code without its tests and comments, as the import-cycle count reads it.
code_of = load_sibling("import-cycles.py").code_of


def files(root):
    return glob.glob(os.path.join(root, "**", "*.rs"), recursive=True)


def main():
    crates = sorted(glob.glob("crates/*/src")) + sorted(glob.glob("drivers/*/src"))
    others = {"src": files("src"), "tests": files("tests"), "fuzz": files("fuzz/fuzz_targets")}
    for c in crates:
        others[c] = files(c)
    words = {}
    for name, fs in others.items():
        found = set()
        for f in fs:
            found.update(re.findall(r"[A-Za-z_][A-Za-z0-9_]*", code_of(f)))
        words[name] = found
    listing = "--list" in sys.argv
    total_fn = unused_fn = total = unused = 0
    for c in crates:
        items = []
        for f in files(c):
            items += [(kind, name, f) for kind, name in ITEM.findall(code_of(f))]
        elsewhere = set().union(*(w for n, w in words.items() if n != c))
        lonely = [(k, n, f) for k, n, f in items if n not in elsewhere]
        fns = [i for i in items if i[0] == "fn"]
        lonely_fns = [i for i in lonely if i[0] == "fn"]
        total += len(items)
        unused += len(lonely)
        total_fn += len(fns)
        unused_fn += len(lonely_fns)
        print(f"{c}: {len(lonely)} of {len(items)} public items named by no other crate "
              f"({len(lonely_fns)} of {len(fns)} functions)")
        if listing:
            for k, n, f in sorted(lonely):
                print(f"    {k} {n}  ({os.path.relpath(f, c)})")
    print(f"all library crates: {unused} of {total} public items named by no other crate "
          f"({unused_fn} of {total_fn} functions)")


if __name__ == "__main__":
    main()
