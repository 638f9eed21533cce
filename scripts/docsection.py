"""Replaces one marked section of a Markdown page that several programs write.

A section runs from `<!-- NAME:begin -->` to `<!-- NAME:end -->` (markers
included); a page without it gets it appended. bmrBenchmark, which rewrites
docs/benchmarks.md, keeps the sections the scripts write
(benchmarks/bmrBenchmarkSupport.h lists their names).
"""
import os
import re


def markers(name):
    return "<!-- %s:begin -->" % name, "<!-- %s:end -->" % name


def write_section(path, name, lines):
    """Writes `lines` (without markers) as the section `name` of the page at `path`."""
    begin, end = markers(name)
    section = "\n".join([begin, ""] + list(lines) + ["", end])
    text = open(path).read() if os.path.exists(path) else "# Benchmarks\n"
    if begin in text and end in text:
        text = re.sub(re.escape(begin) + ".*?" + re.escape(end), lambda _: section, text, flags=re.S)
    else:
        text = text.rstrip("\n") + "\n\n" + section + "\n"
    with open(path, "w") as handle:
        handle.write(text)
