"""The README's commands run as written, top to bottom, in the folder its text names: every file a `metro`
command reads exists there in the repository, or an earlier command wrote it there (`--out`), or the text
before the block copies it there (`cp SRC .`). A newcomer who ran the worked example in
metrology/data/measured and then the production loop from the root met "calibrated.toml: no such file"
(the walk, round 7)."""

import re
import shlex
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: options whose value is a file the command reads
READS = {"--layout", "--layout-before", "--plane", "--points", "--panel", "--true-layout"}
#: options whose value the command writes, or that take a value which is no file
WRITES = {"--out", "--report", "--qif", "--dfq", "--plot", "--truth"}
SUFFIXES = {".toml", ".csv", ".json", ".ply", ".stl", ".parquet", ".step", ".pcd", ".e57"}


def _blocks(text):
    """``(folder, commands, prose)`` per ```bash block: the folder the prose before it names ("[...](DIR);
    from there"), else the root; the block's ``metro`` command lines; the prose since the previous block."""
    out, last = [], 0
    for m in re.finditer(r"```bash\n(.*?)```", text, re.S):
        prose = text[last:m.start()]
        last = m.end()
        there = re.search(r"\]\(([^)]+)\)[^\n]*from there:\s*$", prose)
        folder = ROOT / there.group(1) if there else ROOT
        lines = [ln.split("#")[0].strip() for ln in m.group(1).splitlines()]
        out.append((folder, [ln for ln in lines if ln.startswith("metro ")], prose))
    return out


def _reads(command):
    """The files (relative paths) one ``metro`` command line reads."""
    words = shlex.split(command)[2:]
    files, skip = [], False
    for k, w in enumerate(words):
        if skip:
            skip = False
            continue
        if w in WRITES:
            skip = True
        elif w in READS or not w.startswith("-"):
            v = words[k + 1] if w in READS and k + 1 < len(words) else w
            skip = w in READS
            if Path(v).suffix.lower() in SUFFIXES:
                files.append(v)
    return files


def _written(command):
    words = shlex.split(command)
    return [words[k + 1] for k, w in enumerate(words[:-1]) if w in WRITES]


def test_every_file_a_readme_command_reads_is_there():
    made = set()  # (folder, name) an earlier command wrote, or the prose copied
    missing = []
    for folder, commands, prose in _blocks((ROOT / "README.md").read_text(encoding="utf-8")):
        for src, dst in re.findall(r"`cp (\S+) (\S+)`", prose):
            if (ROOT / src).exists() or (ROOT / Path(src).parent, Path(src).name) in made:
                made.add((folder, Path(src).name) if dst == "." else (folder, dst))
        for c in commands:
            for f in _reads(c):
                if not (folder / f).exists() and (folder, f) not in made:
                    missing.append(f"{f} (in {folder.relative_to(ROOT) or '.'}): {c}")
            made.update((folder, w) for w in _written(c))
    assert not missing, missing
