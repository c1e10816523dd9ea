"""docs/results.md, written by the benchmarks themselves: each bench replaces its own section.

A section sits between ``<!-- bench:NAME -->`` and ``<!-- /bench:NAME -->`` and holds the
bench's table with where it was measured: the machine (CPU model with its family and vector
unit, cores, memory), the command line and the commit (``+ uncommitted changes`` when the tree
was dirty). Nobody edits the numbers by hand; a bench run with ``--results FILE`` rewrites its
section and leaves the rest.
"""

from __future__ import annotations

import datetime as _dt
import os
import platform
import shlex
import subprocess
import sys
from pathlib import Path


def cpu_name(cpuinfo: str) -> str:
    """The first processor of a ``/proc/cpuinfo`` text: its model name, then family, model and
    the widest vector unit (``'AMD EPYC (family 25 model 1, AVX2)'``). A VM's model name can be
    as bare as that, while two VMs of the same name can differ by 1.5-2x in speed and in the SIMD
    kernels numpy and OpenCV choose (which can move the chaotic filter's trajectories by
    centimetres: docs/architecture.md, "Why it is deterministic"); '' when the text names no
    processor."""
    info: dict[str, str] = {}
    for line in cpuinfo.splitlines():
        if not line.strip():
            if info:
                break  # the first processor only
            continue
        key, _, value = line.partition(":")
        info.setdefault(key.strip(), value.strip())
    name = info.get("model name", "")
    if not name:
        return ""
    flags = set(info.get("flags", "").split())
    simd = "AVX-512" if "avx512f" in flags else "AVX2" if "avx2" in flags else "no AVX2" if flags else ""
    detail = [f"family {info['cpu family']} model {info['model']}"] if "cpu family" in info and "model" in info else []
    detail += [simd] if simd else []
    return f"{name} ({', '.join(detail)})" if detail else name


def machine() -> str:
    """'AMD EPYC (family 25 model 1, AVX2), 2 cores, 24 GiB, Linux 6.1' (from /proc where there
    is one)."""
    cpu = platform.processor() or platform.machine()
    try:
        cpu = cpu_name(Path("/proc/cpuinfo").read_text()) or cpu
    except OSError:
        pass
    mem = ""
    try:
        kb = int(Path("/proc/meminfo").read_text().split("MemTotal:", 1)[1].split()[0])
        mem = f", {kb / 2**20:.0f} GiB"
    except (OSError, IndexError, ValueError):
        pass
    return f"{cpu}, {os.cpu_count()} cores{mem}, {platform.system()} {platform.release()}"


def commit(repo: Path | None = None, outputs: tuple = ()) -> str:
    """The checkout's commit ('abc1234' or 'abc1234 + uncommitted changes'), or 'unknown'.
    Changes to ``outputs`` (the benches' own files: the results file, the plot folder; paths
    relative to ``repo``) do not count: a bench run after another in the same session finds the
    first one's table there. The whole checkout is checked, wherever ``repo`` lies in it."""
    cwd = Path(repo or Path.cwd())

    def git(*args: str) -> str:
        return subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True, timeout=10, check=True).stdout

    try:
        rev = git("rev-parse", "--short=12", "HEAD").strip()
        top = git("rev-parse", "--show-toplevel").strip()
        exclude = []
        for o in filter(None, outputs):
            try:  # git refuses a pathspec outside the checkout
                exclude.append(f":(top,exclude){(cwd / o).resolve().relative_to(Path(top).resolve())}")
            except ValueError:
                pass
        dirty = git("status", "--porcelain", "--untracked-files=no", "--", ":/", *exclude).strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return rev + (" + uncommitted changes" if dirty else "")


def section(
    name: str,
    title: str,
    body: str,
    command: str | None = None,
    when: str | None = None,
    where: str | None = None,
    rev: str | None = None,
) -> str:
    """One bench's section, with its markers and provenance line."""
    command = command or shlex.join(["pf-slam", *sys.argv[1:]])
    when = when or _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    where = where or machine()
    rev = rev or commit()
    return (
        f"<!-- bench:{name} -->\n### {title}\n\n"
        f"`{command}` on commit {rev}, {when}; machine: {where}.\n\n{body.rstrip()}\n"
        f"<!-- /bench:{name} -->"
    )


def update(path: str | os.PathLike, name: str, text: str) -> None:
    """Replace section `name` of the results file `path` with `text` (from section()), or append
    it; the file is created with a heading if it does not exist."""
    p = Path(path)
    doc = (
        p.read_text()
        if p.exists()
        else "# Results\n\nWritten by the benchmarks (`make bench`, `make bench-car`, `make bench-scaling`); each section names the machine, the command and the commit it was measured on.\n"
    )
    start, end = f"<!-- bench:{name} -->", f"<!-- /bench:{name} -->"
    i, j = doc.find(start), doc.find(end)
    if i >= 0 and j > i:
        doc = doc[:i] + text + doc[j + len(end) :]
    else:
        doc = doc.rstrip("\n") + "\n\n" + text + "\n"
    p.write_text(doc)
