#!/usr/bin/env python3
"""File-level import graph of the crate's own modules: cycles and upward layer imports.

Usage:
    python3 scripts/import_graph.py [--layers L1,L2,...] [--check] [--dot FILE]
                                    [--include-tests] [--allow-modrs-cycles] [--root DIR]

What it reads
  The library tree is walked from src/lib.rs and the binary tree from src/main.rs by
  following `mod x;` declarations (src/foo.rs or src/foo/mod.rs is crate::foo, and so on at
  any depth; `#[path]` attributes are not supported).  Files under tests/, benches/ and
  examples/ are out of scope.  In the binary (src/main.rs, node "main", and its own modules
  such as src/fmm_command.rs) `mobo::` paths name the library and `crate::` the binary.

What counts as a reference from file A to file B
  A's source with comments (`//`, `//!`, `///`, nested `/* */`) and the contents of string
  and char literals blanked out (so intra-doc links such as [`crate::x::y`] and text in
  strings never count) contains a path to B's module:
    * in `use` statements (braces expanded, `self` inside braces, `as` renames), and
    * anywhere else, paths starting with `crate::`, `$crate::`, `self::`, `super::`
      (repeated `super::` allowed), `mobo::` (binary only), the name of a child module
      declared in the same file (`cells::parse(..)` in a mod.rs), or a name that a `use`
      statement of the file bound to a module (`use crate::fmm::kernels;` then
      `kernels::x::Y`).
  `super`/`self` are relative to the module at that point, including inline modules:
  inside `mod tests { use super::*; }` in src/a/b.rs, `super` is crate::a::b itself (a
  self-reference, ignored), and in src/a/mod.rs `super` is the crate root.
  Each path resolves to the longest prefix that names a module *file*; so `crate::fmm::Fmm`
  is an edge to src/fmm/mod.rs even if mod.rs only re-exports it.  `mod x;` declarations
  are not references.  References of a file to itself are ignored.

Test code
  Items under `#[cfg(test)]` / `#[cfg(all(test, ..))]` (usually `mod tests { .. }`, also
  single test-only functions) and files declared as `#[cfg(test)] mod x;` (and their
  children) are *test code*.  Their edges are kept apart: by default they are NOT part of the
  graph used for cycles and layers, and are only summarised in a separate section (test-only
  cycles and upward imports).  `--include-tests` merges them into the main graph.

Cycles
  Strongly connected components (Tarjan) of the production graph.  They are reported in
  two groups:
    1. cycles among ordinary files, i.e. with every "hub" file removed (a hub is a file
       that declares child module files: src/lib.rs, src/main.rs, the mod.rs files);
    2. the cycles that exist only because they pass through a hub, marked
       "(via mod.rs re-export)": typically a child uses `super::SomeError` defined in its
       mod.rs while the mod.rs re-exports or calls something from the child.
  For each group the elementary cycles of every component are listed (capped), each edge
  with one example `file:line path`.

Layers
  `--layers` is an order from lowest to highest of top-level modules (the first path
  component under src/, e.g. `fmm` for src/fmm/octree.rs; `main` for src/main.rs; binary
  modules such as src/fmm_command.rs are named by their file, `fmm_command`; src/lib.rs is
  `lib`).  A layer may import only layers at or below it; every production edge from a
  lower to a higher layer is reported.  Top-level modules missing from --layers are
  reported as "unlayered".

Exit status: with --check, 1 if a production cycle (either group; hub cycles excepted with
--allow-modrs-cycles) or an upward import is found, else 0.  Without --check, 0.
"""

from __future__ import annotations

import argparse
import os
import re
import sys
from collections import defaultdict
from dataclasses import dataclass, field

LIB_CRATE = "mobo"
IDENT = r"[A-Za-z_][A-Za-z0-9_]*"
MISSING: set = set()  # declared modules whose file was not found (paths into them are skipped)


# --------------------------------------------------------------------------- lexing

def strip_source(src: str) -> str:
    """Blank comments and the contents of string/char literals, keeping offsets and newlines."""
    out = list(src)
    n = len(src)
    i = 0

    def blank(a: int, b: int) -> None:
        for k in range(a, min(b, n)):
            if out[k] != "\n":
                out[k] = " "

    def ident_char(c: str) -> bool:
        return c.isalnum() or c == "_"

    while i < n:
        c = src[i]
        if c == "/" and i + 1 < n and src[i + 1] == "/":
            j = src.find("\n", i)
            j = n if j < 0 else j
            blank(i, j)
            i = j
        elif c == "/" and i + 1 < n and src[i + 1] == "*":
            depth, j = 1, i + 2
            while j < n and depth:
                if src.startswith("/*", j):
                    depth += 1
                    j += 2
                elif src.startswith("*/", j):
                    depth -= 1
                    j += 2
                else:
                    j += 1
            blank(i, j)
            i = j
        elif c in "rb" and (i == 0 or not ident_char(src[i - 1])):
            # raw strings r"..", r#".."#, br#".."#; byte strings b".."; byte chars b'x'
            m = re.match(r'(b?r)(#*)"', src[i:i + 300])
            if m:
                hashes = m.group(2)
                start = i + len(m.group(0))
                end = src.find('"' + hashes, start)
                end = n if end < 0 else end
                blank(start, end)
                i = end + 1 + len(hashes)
            elif c == "b" and i + 1 < n and src[i + 1] in "\"'":
                i += 1  # let the string/char branch handle it on the next round
            else:
                j = i
                while j < n and ident_char(src[j]):
                    j += 1
                i = j
        elif c == '"':
            j = i + 1
            while j < n and src[j] != '"':
                j += 2 if src[j] == "\\" else 1
            blank(i + 1, j)
            i = j + 1
        elif c == "'":
            # char literal or lifetime/label
            if i + 1 < n and src[i + 1] == "\\":
                j = i + 3  # skip the backslash and the escaped character
                while j < n and src[j] != "'" and src[j] != "\n":
                    j += 1
                blank(i + 1, j)
                i = j + 1
            elif i + 2 < n and src[i + 2] == "'":
                blank(i + 1, i + 2)
                i += 3
            else:
                i += 1
        elif ident_char(c):
            j = i
            while j < n and ident_char(src[j]):
                j += 1
            i = j
        else:
            i += 1
    return "".join(out)


def match_close(text: str, open_pos: int) -> int:
    """Index of the bracket closing the one at open_pos (text is stripped)."""
    pairs = {"{": "}", "(": ")", "[": "]"}
    opener = text[open_pos]
    closer = pairs[opener]
    depth = 0
    for k in range(open_pos, len(text)):
        ch = text[k]
        if ch == opener:
            depth += 1
        elif ch == closer:
            depth -= 1
            if depth == 0:
                return k
    return len(text) - 1


def item_end(text: str, pos: int) -> int:
    """End of the item starting at pos: the first `;` outside brackets, or the `}` closing the
    first `{` outside parentheses/brackets."""
    depth = 0
    for k in range(pos, len(text)):
        ch = text[k]
        if ch in "([":
            depth += 1
        elif ch in ")]":
            depth -= 1
        elif depth == 0 and ch == ";":
            return k
        elif depth == 0 and ch == "{":
            return match_close(text, k)
    return len(text) - 1


def line_of(line_starts: list[int], pos: int) -> int:
    import bisect
    return bisect.bisect_right(line_starts, pos)


# --------------------------------------------------------------------------- model

@dataclass
class SrcFile:
    path: str              # relative to root, e.g. src/fmm/octree.rs
    crate: str             # "lib" or "bin"
    mod: tuple             # module segments below the crate root
    is_hub: bool = False   # declares child module files
    test_only: bool = False
    raw: str = ""
    text: str = ""         # stripped
    line_starts: list = field(default_factory=list)
    children: dict = field(default_factory=dict)       # name -> module tuple (file modules)
    inline: list = field(default_factory=list)          # (start, end, name)
    test_spans: list = field(default_factory=list)      # (start, end)

    @property
    def key(self):
        return (self.crate,) + self.mod

    @property
    def node(self) -> str:
        if self.crate == "bin" and not self.mod:
            return "main"
        return self.path

    @property
    def top(self) -> str:
        if not self.mod:
            return "main" if self.crate == "bin" else "lib"
        return self.mod[0]


@dataclass
class Edge:
    src: str
    dst: str
    line: int
    text: str
    test: bool


DECL_RE = re.compile(r"\b(?:pub(?:\s*\([^)]*\))?\s+)?mod\s+(" + IDENT + r")\s*([;{])")
CFG_TEST_RE = re.compile(r"#\s*\[\s*cfg\s*\(\s*(?:test\s*\)|all\s*\(\s*test\b)")
INNER_CFG_TEST_RE = re.compile(r"#!\s*\[\s*cfg\s*\(\s*test\s*\)\s*\]")


def analyse_structure(f: SrcFile) -> None:
    t = f.text
    f.line_starts = [0] + [m.end() for m in re.finditer("\n", t)]
    if INNER_CFG_TEST_RE.search(t):
        f.test_only = True
    # test spans: #[cfg(test)] followed by (attributes and) an item
    for m in CFG_TEST_RE.finditer(t):
        attr_open = t.index("[", m.start())
        k = match_close(t, attr_open) + 1
        while True:
            mm = re.match(r"\s*#\s*\[", t[k:])
            if not mm:
                break
            k = match_close(t, k + mm.end() - 1) + 1
        f.test_spans.append((m.start(), item_end(t, k)))
    # inline modules
    for m in DECL_RE.finditer(t):
        if m.group(2) == "{":
            brace = m.end() - 1
            f.inline.append((brace, match_close(t, brace), m.group(1)))


def in_test(f: SrcFile, pos: int) -> bool:
    return f.test_only or any(a <= pos <= b for a, b in f.test_spans)


def inline_path(f: SrcFile, pos: int) -> tuple:
    spans = sorted((s for s in f.inline if s[0] < pos <= s[1]), key=lambda s: s[0])
    return tuple(s[2] for s in spans)


def discover(root: str) -> dict:
    """Walk lib.rs and main.rs through `mod x;` declarations. Returns key -> SrcFile."""
    files: dict = {}

    def load(path: str, crate: str, mod: tuple, test_only: bool) -> None:
        full = os.path.join(root, path)
        with open(full, encoding="utf-8") as fh:
            raw = fh.read()
        f = SrcFile(path=path, crate=crate, mod=mod, test_only=test_only, raw=raw)
        f.text = strip_source(raw)
        analyse_structure(f)
        files[f.key] = f
        base = os.path.dirname(path)
        stem = os.path.splitext(os.path.basename(path))[0]
        if stem in ("mod", "lib", "main"):
            child_dir = base
        else:
            child_dir = os.path.join(base, stem)
        for m in DECL_RE.finditer(f.text):
            if m.group(2) != ";":
                continue
            name = m.group(1)
            ipath = inline_path(f, m.start())
            cdir = os.path.join(child_dir, *ipath)
            cands = [os.path.join(cdir, name + ".rs"), os.path.join(cdir, name, "mod.rs")]
            found = next((c for c in cands if os.path.isfile(os.path.join(root, c))), None)
            if not found:
                print(f"warning: {path}: module `{name}` has no file", file=sys.stderr)
                MISSING.add((crate,) + mod + ipath + (name,))
                continue
            cmod = mod + ipath + (name,)
            if not ipath:
                f.children[name] = cmod
            f.is_hub = True
            load(found, crate, cmod, test_only or in_test(f, m.start()))

    load("src/lib.rs", "lib", (), False)
    if os.path.isfile(os.path.join(root, "src/main.rs")):
        load("src/main.rs", "bin", (), False)
    # files under src/ that no declaration reaches
    seen = {f.path for f in files.values()}
    for dp, _, fns in os.walk(os.path.join(root, "src")):
        for fn in sorted(fns):
            if fn.endswith(".rs"):
                rel = os.path.relpath(os.path.join(dp, fn), root)
                if rel not in seen:
                    print(f"warning: {rel} is not reached by any `mod` declaration", file=sys.stderr)
    return files


# --------------------------------------------------------------------------- use trees

TOKEN_RE = re.compile(r"\s*(::|\{|\}|,|\*|\$?" + IDENT + r")")


def parse_use_tree(text: str, start: int, end: int):
    """Leaves of the use tree in text[start:end] as (segments, pos_of_last_segment, alias)."""
    toks = []
    k = start
    while k < end:
        m = TOKEN_RE.match(text, k, end)
        if not m:
            k += 1
            continue
        toks.append((m.group(1), m.start(1)))
        k = m.end()
    leaves = []
    idx = 0

    def tree(prefix: list):
        nonlocal idx
        segs = list(prefix)
        last_pos = toks[idx][1] if idx < len(toks) else start
        while idx < len(toks):
            tok, pos = toks[idx]
            if tok == "{":
                idx += 1
                while idx < len(toks) and toks[idx][0] != "}":
                    if toks[idx][0] == ",":
                        idx += 1
                        continue
                    tree(segs)
                idx += 1  # skip }
                return
            if tok == "::":
                idx += 1
                continue
            if tok in (",", "}"):
                break
            if tok == "as":
                idx += 1
                alias = toks[idx][0] if idx < len(toks) else None
                idx += 1
                leaves.append((segs, last_pos, alias))
                return
            if tok == "self" and prefix and len(segs) == len(prefix):
                # `self` inside braces: the prefix module itself
                idx += 1
                if idx < len(toks) and toks[idx][0] == "as":
                    idx += 1
                    alias = toks[idx][0] if idx < len(toks) else None
                    idx += 1
                    leaves.append((segs, pos, alias))
                else:
                    leaves.append((segs, pos, segs[-1] if segs else None))
                return
            segs = segs + [tok]
            last_pos = pos
            idx += 1
        leaves.append((segs, last_pos, None))

    if toks and toks[0][0] == "::":
        return []  # ::extern_crate::..
    while idx < len(toks):
        if toks[idx][0] == ",":
            idx += 1
            continue
        before = idx
        tree([])
        if idx == before:
            idx += 1
    return leaves


# --------------------------------------------------------------------------- resolution

class Resolver:
    def __init__(self, files: dict):
        self.files = files

    def file_for(self, abs_key: tuple):
        """Longest prefix of abs_key (crate, segs..) naming a module file."""
        if any(abs_key[:n] in MISSING for n in range(2, len(abs_key) + 1)):
            return None
        for n in range(len(abs_key), 0, -1):
            f = self.files.get(abs_key[:n])
            if f is not None:
                return f
        return None

    def absolute(self, f: SrcFile, pos: int, segs: list, aliases: dict):
        """Absolute key (crate, segs..) of a path, or None when it is not the crate's."""
        if not segs:
            return None
        head = segs[0]
        here = f.mod + inline_path(f, pos)
        if head in ("crate", "$crate"):
            return (f.crate,) + tuple(segs[1:])
        if head == LIB_CRATE and f.crate == "bin":
            return ("lib",) + tuple(segs[1:])
        if head == "self":
            return (f.crate,) + here + tuple(segs[1:])
        if head == "super":
            cur = list(here)
            rest = list(segs)
            while rest and rest[0] == "super":
                if not cur:
                    return None
                cur.pop()
                rest.pop(0)
            return (f.crate,) + tuple(cur) + tuple(rest)
        if head in aliases:
            return aliases[head] + tuple(segs[1:])
        if head in f.children and not inline_path(f, pos):
            return (f.crate,) + f.children[head] + tuple(segs[1:])
        if head in f.children:
            # inside an inline module (e.g. tests with `use super::*`): still the child
            return (f.crate,) + f.children[head] + tuple(segs[1:])
        return None


def collect_edges(files: dict) -> list:
    res = Resolver(files)
    edges: list = []
    use_re = re.compile(r"\buse\s+(?=[\w:{$])")
    for f in files.values():
        t = f.text
        aliases: dict = {}
        use_spans = []
        pending = []
        for m in use_re.finditer(t):
            # skip `use` that is part of an identifier path (e.g. `r#use`); keyword only
            end = t.find(";", m.end())
            if end < 0:
                continue
            use_spans.append((m.start(), end))
            for segs, pos, alias in parse_use_tree(t, m.end(), end):
                pending.append((segs, pos, alias))
        # first pass: module aliases bound by use statements
        for segs, pos, alias in pending:
            if not segs or segs[-1] == "*":
                continue
            ab = res.absolute(f, pos, segs, {})
            if ab is None:
                continue
            if ab in files:
                name = alias or segs[-1]
                if name not in ("self", "super", "crate", "_"):
                    aliases[name] = ab
        for segs, pos, alias in pending:
            ab = res.absolute(f, pos, [s for s in segs if s != "*"], aliases)
            if ab is None:
                continue
            target = res.file_for(ab)
            if target is None or target is f:
                continue
            text = "use " + "::".join(segs)
            edges.append(Edge(f.node, target.node, line_of(f.line_starts, pos), text,
                              in_test(f, pos)))
        # other paths
        heads = {"crate", "self", "super"} | set(aliases) | set(f.children)
        if f.crate == "bin":
            heads.add(LIB_CRATE)
        head_alt = "|".join(sorted((re.escape(h) for h in heads), key=len, reverse=True))
        path_re = re.compile(r"(?<![\w.$])(?<!::)(\$?(?:" + head_alt + r"))((?:\s*::\s*" + IDENT + r")+)")
        use_spans.sort()
        for m in path_re.finditer(t):
            if any(a <= m.start() <= b for a, b in use_spans):
                continue
            tail = re.findall(IDENT, m.group(2))
            segs = [m.group(1)] + tail
            ab = res.absolute(f, m.start(), segs, aliases)
            if ab is None:
                continue
            target = res.file_for(ab)
            if target is None or target is f:
                continue
            text = re.sub(r"\s+", "", m.group(0))
            edges.append(Edge(f.node, target.node, line_of(f.line_starts, m.start()), text,
                              in_test(f, m.start())))
    return edges


# --------------------------------------------------------------------------- graph algorithms

def tarjan(nodes, adj) -> list:
    index, low, on, stack, out = {}, {}, set(), [], []
    counter = [0]
    sys.setrecursionlimit(10000)

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(adj.get(v, ())):
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
            out.append(sorted(comp))

    for v in sorted(nodes):
        if v not in index:
            visit(v)
    return out


def simple_cycles(comp: list, adj, cap: int) -> tuple:
    """Elementary cycles inside one component, each starting at its smallest node.
    Returns (cycles, truncated)."""
    order = {v: i for i, v in enumerate(comp)}
    members = set(comp)
    cycles: list = []
    for s in comp:
        path = [s]
        on_path = {s}

        def dfs(v) -> bool:
            for w in sorted(adj.get(v, ())):
                if w not in members or order[w] < order[s]:
                    continue
                if w == s:
                    cycles.append(list(path))
                    if len(cycles) >= cap:
                        return True
                elif w not in on_path:
                    path.append(w)
                    on_path.add(w)
                    if dfs(w):
                        return True
                    path.pop()
                    on_path.discard(w)
            return False

        if dfs(s):
            return cycles, True
    return cycles, False


# --------------------------------------------------------------------------- report

def short(node: str) -> str:
    if node == "main":
        return "main"
    s = node[len("src/"):] if node.startswith("src/") else node
    return s[:-3] if s.endswith(".rs") else s


def main() -> int:
    ap = argparse.ArgumentParser(
        description="File-level import graph of the crate: cycles and upward layer imports.")
    ap.add_argument("--layers", default="",
                    help="comma-separated top-level modules, lowest first (e.g. durable,check,...,main)")
    ap.add_argument("--check", action="store_true",
                    help="exit 1 if a production cycle or an upward import is found")
    ap.add_argument("--dot", metavar="FILE", help="write the folder-level graph in Graphviz dot")
    ap.add_argument("--include-tests", action="store_true",
                    help="treat #[cfg(test)] code like production code")
    ap.add_argument("--allow-modrs-cycles", action="store_true",
                    help="with --check, do not fail on cycles that exist only through mod.rs/lib.rs/main.rs")
    ap.add_argument("--max-cycles", type=int, default=200,
                    help="cap on elementary cycles listed per component (default 200)")
    ap.add_argument("--root", default=os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                    help="crate root (default: the parent of scripts/)")
    args = ap.parse_args()

    files = discover(args.root)
    by_node = {f.node: f for f in files.values()}
    edges = collect_edges(files)
    if args.include_tests:
        for e in edges:
            e.test = False

    prod = [e for e in edges if not e.test]
    tests = [e for e in edges if e.test]

    def examples(es):
        ex = {}
        for e in sorted(es, key=lambda e: (e.src, e.line)):
            ex.setdefault((e.src, e.dst), e)
        return ex

    def adjacency(es, keep=lambda n: True):
        adj = defaultdict(set)
        for e in es:
            if keep(e.src) and keep(e.dst):
                adj[e.src].add(e.dst)
        return adj

    hubs = {n for n, f in by_node.items() if f.is_hub}
    nodes = sorted(by_node)
    failed = False
    out = []
    w = out.append

    w(f"import graph: {len(nodes)} files, {len(examples(prod))} production file edges "
      f"({len(prod)} references), {len(examples(tests))} test-only file edges"
      + (" (tests merged)" if args.include_tests else ""))

    def cycle_lines(cyc, ex, mark=""):
        lines = ["  " + " -> ".join(short(n) for n in cyc + [cyc[0]]) + mark]
        for a, b in zip(cyc, cyc[1:] + cyc[:1]):
            e = ex[(a, b)]
            lines.append(f"      {short(a)} -> {short(b)}: {by_node[a].path}:{e.line}  {e.text}")
        return lines

    def report_cycles(es, title_plain, title_hub, is_test_section=False):
        nonlocal failed
        ex = examples(es)
        adj_plain = adjacency(es, lambda n: n not in hubs)
        adj_full = adjacency(es)
        comps_plain = [c for c in tarjan([n for n in nodes if n not in hubs], adj_plain) if len(c) > 1]
        comps_full = [c for c in tarjan(nodes, adj_full) if len(c) > 1]
        plain_cycles = []
        for comp in comps_plain:
            cyc, trunc = simple_cycles(comp, adj_plain, args.max_cycles)
            plain_cycles.append((comp, cyc, trunc))
        n_plain = sum(len(c) for _, c, _ in plain_cycles)
        same = [x for x in plain_cycles if len({by_node[n].top for n in x[0]}) == 1]
        cross = [x for x in plain_cycles if len({by_node[n].top for n in x[0]}) > 1]
        w("")
        w(f"== {title_plain}: {len(comps_plain)} components, {n_plain} elementary cycles")
        for label, group in (("inside one top-level folder", same), ("across top-level folders", cross)):
            if not group:
                w(f" -- {label}: none")
                continue
            w(f" -- {label}:")
            for comp, cyc, trunc in group:
                if len(comp) > 2 or len(cyc) > 1:
                    w(f" component of {len(comp)} files: {', '.join(short(n) for n in comp)}")
                for c in cyc:
                    out.extend(cycle_lines(c, ex))
                if trunc:
                    w(f"  ... more cycles (capped at {args.max_cycles})")
        # cycles through hubs
        hub_cycles = []
        for comp in comps_full:
            if not any(n in hubs for n in comp):
                continue
            cyc, trunc = simple_cycles(comp, adj_full, args.max_cycles)
            cyc = [c for c in cyc if any(n in hubs for n in c)]
            hub_cycles.append((comp, cyc, trunc))
        n_hub = sum(len(c) for _, c, _ in hub_cycles)
        w("")
        w(f"== {title_hub}: {n_hub} elementary cycles through mod.rs/lib.rs/main.rs"
          f" (in {len(hub_cycles)} components)")
        for comp, cyc, trunc in hub_cycles:
            w(f" component of {len(comp)} files: {', '.join(short(n) for n in comp)}")
            for c in sorted(cyc, key=lambda c: (len(c), c)):
                out.extend(cycle_lines(c, ex, "   (via mod.rs re-export)"))
            if trunc:
                w(f"  ... more cycles (capped at {args.max_cycles})")
        if not is_test_section:
            if n_plain or (n_hub and not args.allow_modrs_cycles):
                failed = True
        return n_plain, n_hub

    report_cycles(prod, "Cycles between files (production code, hubs excluded)",
                  "Cycles through hub files (production code)")

    # layers
    layers = [x.strip() for x in args.layers.split(",") if x.strip()]
    rank = {name: i for i, name in enumerate(layers)}
    tops = sorted({f.top for f in files.values()})

    def upward(es):
        ups = []
        for e in sorted(es, key=lambda e: (e.src, e.line, e.dst)):
            a, b = by_node[e.src].top, by_node[e.dst].top
            if a != b and a in rank and b in rank and rank[b] > rank[a]:
                ups.append(e)
        return ups

    if layers:
        unknown = [x for x in layers if x not in tops]
        if unknown:
            w("")
            w(f"note: --layers names modules that do not exist: {', '.join(unknown)}")
        ups = upward(prod)
        w("")
        w(f"== Upward imports (production code; order {' < '.join(layers)}): {len(ups)} references, "
          f"{len({(e.src, e.dst) for e in ups})} file edges")
        for e in ups:
            a, b = by_node[e.src].top, by_node[e.dst].top
            w(f"  {a} -> {b}: {by_node[e.src].path}:{e.line}  {e.text}   (-> {short(e.dst)})")
        if ups:
            failed = True
        unl = [t for t in tops if t not in rank]
        w("")
        if unl:
            w("== Unlayered top-level modules (not in --layers):")
            for t in unl:
                n_out = sum(1 for e in prod if by_node[e.src].top == t and by_node[e.dst].top != t)
                n_in = sum(1 for e in prod if by_node[e.dst].top == t and by_node[e.src].top != t)
                w(f"  {t}: {n_out} references out, {n_in} in")
        else:
            w("== Unlayered top-level modules: none")

    if tests and not args.include_tests:
        # what the test code adds
        all_es = prod + tests
        full_comps = {tuple(c) for c in tarjan(nodes, adjacency(all_es)) if len(c) > 1}
        prod_comps = {tuple(c) for c in tarjan(nodes, adjacency(prod)) if len(c) > 1}
        new = sorted(full_comps - prod_comps)
        w("")
        w(f"== Test code (#[cfg(test)]), not counted above: {len(examples(tests))} file edges")
        if new:
            w(" components that change when test edges are added:")
            ex = examples(all_es)
            for comp in new:
                w(f"  {', '.join(short(n) for n in comp)}")
                test_ex = examples(tests)
                for (a, b), e in sorted(test_ex.items()):
                    if a in comp and b in comp:
                        w(f"      test edge {short(a)} -> {short(b)}: {by_node[a].path}:{e.line}  {e.text}")
        else:
            w(" no new cycles")
        if layers:
            tups = upward(tests)
            w(f" upward imports in test code: {len(tups)}")
            for e in tups:
                a, b = by_node[e.src].top, by_node[e.dst].top
                w(f"  {a} -> {b}: {by_node[e.src].path}:{e.line}  {e.text}")

    if args.dot:
        counts = defaultdict(int)
        for e in prod:
            a, b = by_node[e.src].top, by_node[e.dst].top
            if a != b:
                counts[(a, b)] += 1
        with open(args.dot, "w", encoding="utf-8") as fh:
            fh.write("digraph mobo {\n  rankdir=BT;\n  node [shape=box];\n")
            for t in tops:
                fh.write(f'  "{t}"{" [style=dashed]" if layers and t not in rank else ""};\n')
            for (a, b), c in sorted(counts.items()):
                up = a in rank and b in rank and rank[b] > rank[a]
                attrs = f'label="{c}"' + (", color=red, penwidth=2" if up else "")
                fh.write(f'  "{a}" -> "{b}" [{attrs}];\n')
            fh.write("}\n")
        w("")
        w(f"wrote {args.dot}")

    print("\n".join(out))
    if args.check and failed:
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
