#!/usr/bin/env python3
"""Functions a reader can hold (issue 64): fails when a C++ or Python function
is longer than 150 lines, or a file longer than 800 lines does not say why at
its top (its leading comment holds "Over 800 lines" and the reason).

Function lengths are lizard's (https://github.com/terryyin/lizard): from the
line of the function's name to its last line, blank and comment lines included.

    python3 scripts/check-code-size.py            # the repository
    python3 scripts/check-code-size.py FILE ...   # these files only
    python3 scripts/check-code-size.py --self-test  # the check against made-up files
"""
import argparse
import pathlib
import re
import sys
import tempfile

import lizard

MAX_FUNCTION_LINES = 150
MAX_FILE_LINES = 800
FOLDERS = ("src", "include", "apps", "wrapping", "test", "benchmarks", "scripts", "examples")
SUFFIXES = {".cxx", ".h", ".hxx", ".py"}
# Inputs the tests read, not code a contributor reads.
SKIPPED = ("test/data/", "test/layering/")
REASON = re.compile(r"over\s+800\s+lines", re.IGNORECASE)


def leading_comment(text, python):
    """The comment lines at the top of a file (C++ // or /* */, Python # or a docstring)."""
    line_comment = ("#",) if python else ("//",)
    lines = []
    in_block = False
    for line in text.splitlines():
        stripped = line.strip()
        if in_block:
            lines.append(stripped)
            if stripped.endswith("*/") or stripped.endswith('"""'):
                in_block = False
            continue
        if stripped.startswith(line_comment) or not stripped:
            lines.append(stripped)
            continue
        if stripped.startswith(('"""', 'r"""') if python else ("/*",)):
            lines.append(stripped)
            in_block = not (len(stripped) > 3 and (stripped.endswith("*/") or stripped.endswith('"""')))
            continue
        break
    return " ".join(re.sub(r"^(//+|#+|/\*+|\*+|r?\"\"\")\s*", "", line) for line in lines)


def source_files(root):
    for folder in FOLDERS:
        for path in sorted((root / folder).rglob("*")):
            relative = path.relative_to(root).as_posix()
            if path.suffix in SUFFIXES and path.is_file() and not relative.startswith(SKIPPED):
                yield path


def problems_of(path, root):
    text = path.read_text(encoding="utf-8")
    relative = path.relative_to(root).as_posix() if path.is_relative_to(root) else str(path)
    found = []
    lines = text.count("\n") + (0 if text.endswith("\n") or not text else 1)
    if lines > MAX_FILE_LINES and not REASON.search(leading_comment(text, path.suffix == ".py")):
        found.append(f"{relative}: {lines} lines, over {MAX_FILE_LINES}, and its top does not say why "
                     f"(\"Over {MAX_FILE_LINES} lines: ...\" in its leading comment); split it or give the reason")
    for function in lizard.analyze_file.analyze_source_code(str(path), text).function_list:
        if function.length > MAX_FUNCTION_LINES:
            found.append(f"{relative}:{function.start_line}: {function.long_name} is {function.length} lines, "
                         f"over {MAX_FUNCTION_LINES}; split it along its ideas")
    return found


def self_test():
    """Made-up files on both sides of each limit; returns the failures."""
    def function(lines):  # a C++ function of `lines` lines from its name to its closing brace
        return "int\nf()\n{\n" + "  int x = 0;\n" * (lines - 4) + "  return x;\n}\n"

    def long_file(reason):
        head = "// A file. Over 800 lines: a reason.\n" if reason else "// A file.\n"
        return head + "".join(f"int g{k}() {{ return {k}; }}\n" for k in range(MAX_FILE_LINES))

    cases = {
        "function-at-limit.cxx": (function(MAX_FUNCTION_LINES), 0),
        "function-over-limit.cxx": (function(MAX_FUNCTION_LINES + 1), 1),
        "file-over-limit-without-reason.cxx": (long_file(False), 1),
        "file-over-limit-with-reason.cxx": (long_file(True), 0),
        "python-over-limit.py": ("def f():\n" + "    x = 1\n" * MAX_FUNCTION_LINES + "    return x\n", 1),
    }
    failures = []
    with tempfile.TemporaryDirectory() as folder:
        root = pathlib.Path(folder)
        for name, (text, expected) in cases.items():
            (root / name).write_text(text, encoding="utf-8")
            found = problems_of(root / name, root)
            if len(found) != expected:
                failures.append(f"{name}: expected {expected} problem(s), found {found}")
    return failures


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("files", nargs="*", type=pathlib.Path)
    parser.add_argument("--root", type=pathlib.Path, default=pathlib.Path(__file__).resolve().parent.parent)
    parser.add_argument("--self-test", action="store_true", help="check the check on made-up files")
    arguments = parser.parse_args()
    if arguments.self_test:
        failures = self_test()
        print("\n".join(failures) or "check-code-size self-test: every made-up file judged as expected")
        return 1 if failures else 0
    root = arguments.root.resolve()
    files = [path.resolve() for path in arguments.files] if arguments.files else list(source_files(root))
    problems = [problem for path in files for problem in problems_of(path, root)]
    for problem in problems:
        print(problem)
    print(f"check-code-size: {len(files)} files, {len(problems)} problem(s)")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
