#!/usr/bin/env python3
"""docs/PYTHON.md's examples, run against a physd of their own, so that they cannot rot.

Every fenced block whose info string is exactly `python` is run; other blocks (`sh`, `text`,
`pycon`, ...) are not. The blocks run in order, in one namespace, as one session in a child
process (what one block defines, the next may use), with tracebacks naming docs/PYTHON.md and
its line numbers. The examples say `pc.Client(domain=0, ...)`: in the child, physclient.Client
is a subclass that puts the test daemon's domain and Cyclone XML (test_physclient.Daemon: a
domain and a discovery tag of this process) in place of what the example gives, and nothing
else. The session must exit with 0 and leave no world behind on the daemon (the docs' first
example promises that a script's worlds go with it). ctest runs this file as
physclient_python_docs (client_sdk/python/CMakeLists.txt).
"""
import os
import re
import subprocess
import sys
import tempfile
import unittest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from test_physclient import SOURCE_DIR, Daemon  # noqa: E402

DOC = os.path.join(SOURCE_DIR, "docs", "PYTHON.md")
FENCE = re.compile(r"^```(.*)$")

DAEMON = None


def setUpModule():
    global DAEMON
    DAEMON = Daemon("physd-python-docs")


def tearDownModule():
    rc = DAEMON.stop()
    if rc != 0:
        raise AssertionError(f"physd did not exit cleanly on SIGTERM: {rc}")


def python_blocks(path):
    """[(first line number, code)] of the ```python blocks of a Markdown file."""
    blocks, info, start, lines = [], None, 0, []
    with open(path) as f:
        for n, line in enumerate(f, 1):
            m = FENCE.match(line.rstrip("\n"))
            if info is None:
                if m:
                    info, start, lines = m.group(1).strip(), n + 1, []
            elif line.rstrip() == "```":
                if info == "python":
                    blocks.append((start, "".join(lines)))
                info = None
            else:
                lines.append(line)
    if info is not None:
        raise ValueError(f"{path}: a block opened at line {start - 1} is not closed")
    return blocks


RUNNER = """\
import sys
import physclient as _pc

DOMAIN, XML, DOC, BLOCKS = {domain!r}, {xml!r}, {doc!r}, {blocks!r}


class Client(_pc.Client):
    \"\"\"The docs' Client on the test's daemon (its domain and Cyclone XML).\"\"\"

    def __init__(self, **kw):
        kw["domain"], kw["cyclone_xml"] = DOMAIN, XML
        kw.setdefault("connect_timeout", 30.0)
        super().__init__(**kw)


_pc.Client = Client
session = {{"__name__": "__main__"}}
for line, code in BLOCKS:
    print(f"--- {{DOC}}:{{line}}", flush=True)
    exec(compile("\\n" * (line - 1) + code, DOC, "exec"), session)
print("--- all blocks ran", flush=True)
"""


class DocsExamples(unittest.TestCase):
    def test_the_python_blocks_run(self):
        blocks = python_blocks(DOC)
        self.assertGreaterEqual(len(blocks), 6, "fewer ```python blocks than the docs have")
        with DAEMON.client(name="docs-check") as c:
            c.connect()
            before = {s.world for s in c.list_worlds()}
            with tempfile.TemporaryDirectory() as d:
                script = os.path.join(d, "python_md.py")
                with open(script, "w") as f:
                    f.write(RUNNER.format(domain=DAEMON.domain, xml=DAEMON.xml_text,
                                          doc="docs/PYTHON.md", blocks=blocks))
                r = subprocess.run([sys.executable, script], capture_output=True, text=True,
                                   timeout=150, cwd=SOURCE_DIR)
            out = r.stdout + r.stderr
            self.assertEqual(r.returncode, 0, out)
            self.assertIn("--- all blocks ran", r.stdout, out)
            left = [s.name for s in c.list_worlds() if s.world not in before]
            self.assertEqual(left, [], "worlds the docs' examples left on the daemon")

    def test_the_first_example_says_worlds_are_durable(self):
        line, first = python_blocks(DOC)[0]
        self.assertIn("create_world", first, f"docs/PYTHON.md:{line} is not the first example")
        self.assertRegex(first, r"(?i)durable", "the first example says worlds are durable")
        self.assertIn("ephemeral=True", first, "... and how to make one ephemeral")
        self.assertRegex(first, r"with client\.create_world\(",
                         "... and shows the block that destroys it")


if __name__ == "__main__":
    unittest.main()
