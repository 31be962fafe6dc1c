#!/usr/bin/env python3
"""Lines of each C++ function body, by brace matching (issue 44: none over 200 lines in
protocol/, server/ and client_sdk/).

  scripts/function_sizes.py [--max N] [--top K] [PATH...]

PATHs are files or folders (.cpp, .h); the default is the C++ the rule covers. A function
is an outermost brace block whose header ends in a parameter list (a lambda inside it counts
as its lines); class, namespace and initializer blocks are walked through. Comments, strings
and character literals are skipped. Exit status 1 when a function passes --max.
"""

import argparse
import os
import re
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DEFAULT = ["protocol/src", "protocol/include", "server/src", "server/include", "server/main.cpp",
           "client_sdk/src", "client_sdk/include", "client_sdk/python/src"]
CONTROL = re.compile(r"^(if|for|while|switch|catch|do|else|return)\b")


def strip(text):
    """The text with comments, strings and char literals blanked (newlines kept)."""
    out, i, n = [], 0, len(text)
    while i < n:
        c = text[i]
        if text.startswith("//", i):
            j = text.find("\n", i)
            j = n if j < 0 else j
            out.append(" " * (j - i))
            i = j
        elif text.startswith("/*", i):
            j = text.find("*/", i + 2)
            j = n if j < 0 else j + 2
            out.append(re.sub(r"[^\n]", " ", text[i:j]))
            i = j
        elif c == 'R' and text.startswith('R"', i) and (i == 0 or not text[i - 1].isalnum()):
            k = text.find("(", i)
            delim = ")" + text[i + 2:k] + '"'
            j = text.find(delim, k)
            j = n if j < 0 else j + len(delim)
            out.append(re.sub(r"[^\n]", " ", text[i:j]))
            i = j
        elif c in "\"'":
            # A digit separator (1'000) is not a literal.
            if c == "'" and i > 0 and text[i - 1].isalnum() and i + 1 < n and text[i + 1].isalnum():
                out.append(" ")
                i += 1
                continue
            j = i + 1
            while j < n and text[j] != c:
                j += 2 if text[j] == "\\" else 1
            j = min(j + 1, n)
            out.append(re.sub(r"[^\n]", " ", text[i:j]))
            i = j
        else:
            out.append(c)
            i += 1
    return "".join(out)


def header_name(header):
    """The function's name from the text before its body, or None if not a function."""
    h = " ".join(l for l in header.split("\n") if not l.lstrip().startswith("#"))
    h = " ".join(h.split())
    if not h or CONTROL.match(h):
        return None
    # Strip a trailing member-initializer list: `) : a(x), b{y}` ends in `)` or `}`.
    m = re.search(r"\)\s*(const|noexcept|override|final|mutable|->[^{;]*|\s)*$", h)
    if not m:
        init = re.search(r"\)\s*:\s*[A-Za-z_]", h)
        if not init:
            return None
    if "=" in h.split("(")[0] and "operator" not in h:  # x = [](..) {  or  T x = {...}
        return None
    name = re.search(r"([~A-Za-z_][\w:~]*(?:operator\s*[^\s(]+)?)\s*(?:<[^()]*>)?\s*\(", h)
    if not name or CONTROL.match(name.group(1)):
        return None
    return name.group(1)


def functions(path):
    text = strip(open(path, encoding="utf-8", errors="replace").read())
    result = []
    depth_in_fn = 0  # > 0 inside a function body
    start_line = 0
    name = None
    header_start = 0
    line = 1
    for i, c in enumerate(text):
        if c == "\n":
            line += 1
        elif c == "{":
            if depth_in_fn:
                depth_in_fn += 1
                continue
            n = header_name(text[header_start:i])
            if n:
                depth_in_fn, start_line, name = 1, line, n
            header_start = i + 1
        elif c == "}":
            if depth_in_fn:
                depth_in_fn -= 1
                if depth_in_fn == 0:
                    result.append((line - start_line + 1, name, start_line))
                    header_start = i + 1
            else:
                header_start = i + 1
        elif c == ";" and not depth_in_fn:
            header_start = i + 1
        elif c == ":" and not depth_in_fn and text[header_start:i].strip() in (
                "public", "private", "protected"):
            header_start = i + 1
    return result


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--max", type=int, default=200)
    ap.add_argument("--top", type=int, default=10)
    ap.add_argument("paths", nargs="*")
    args = ap.parse_args()
    paths = args.paths or [os.path.join(ROOT, p) for p in DEFAULT]
    files = []
    for p in paths:
        if os.path.isdir(p):
            for d, _, names in os.walk(p):
                files += [os.path.join(d, f) for f in names if f.endswith((".cpp", ".h"))
                          and not f.endswith("_generated.h")]
        elif os.path.exists(p):
            files.append(p)
    rows = []
    for f in sorted(files):
        rows += [(n, fn, os.path.relpath(f, ROOT), ln) for n, fn, ln in functions(f)]
    rows.sort(reverse=True)
    for n, fn, f, ln in rows[:args.top]:
        print(f"{n:5d}  {f}:{ln}  {fn}")
    over = [r for r in rows if r[0] > args.max]
    print(f"{len(rows)} functions in {len(files)} files; {len(over)} over {args.max} lines")
    return 1 if over else 0


if __name__ == "__main__":
    sys.exit(main())
