"""docs/results.md sections: a bench rewrites its own section and leaves the rest as it was."""

from __future__ import annotations

import subprocess

from pf_slam_tools.bench import results


def test_a_bench_replaces_its_section_and_keeps_the_others(tmp_path):
    p = tmp_path / "results.md"
    a1 = results.section(
        "carmen_single",
        "CARMEN",
        "| a |\n|---|\n| 1 |",
        command="pf-slam bench carmen",
        when="2026-01-01 00:00 UTC",
        where="cpu, 2 cores",
        rev="abc",
    )
    b1 = results.section(
        "car_single",
        "Car",
        "| b |\n|---|\n| 2 |",
        command="pf-slam bench car",
        when="2026-01-01 00:00 UTC",
        where="cpu, 2 cores",
        rev="abc",
    )
    results.update(p, "carmen_single", a1)
    results.update(p, "car_single", b1)
    doc = p.read_text()
    assert doc.startswith("# Results") and doc.index("| 1 |") < doc.index("| 2 |")
    assert "`pf-slam bench carmen` on commit abc, 2026-01-01 00:00 UTC; machine: cpu, 2 cores." in doc
    a2 = results.section(
        "carmen_single",
        "CARMEN",
        "| a |\n|---|\n| 3 |",
        command="pf-slam bench carmen",
        when="2026-01-02 00:00 UTC",
        where="cpu, 2 cores",
        rev="def",
    )
    results.update(p, "carmen_single", a2)
    doc2 = p.read_text()
    assert "| 1 |" not in doc2 and "| 3 |" in doc2 and "commit def" in doc2
    assert doc2.count("<!-- bench:carmen_single -->") == 1 and b1 in doc2  # the car section untouched
    assert doc2.index("| 3 |") < doc2.index("| 2 |")  # in its place, not appended


def test_provenance_names_a_machine_and_a_commit():
    assert "cores" in results.machine()
    rev = results.commit()
    assert rev == "unknown" or len(rev.split()[0]) == 12


def test_cpu_name_tells_apart_machines_of_one_model_name():
    """Two VMs both called 'AMD EPYC': the family, model and vector unit say which is which."""
    zen3 = "processor\t: 0\ncpu family\t: 25\nmodel\t\t: 1\nmodel name\t: AMD EPYC\nflags\t\t: fpu sse2 avx2 fma\n\n"
    zen4 = zen3.replace("model\t\t: 1", "model\t\t: 17").replace("avx2 fma", "avx2 fma avx512f avx512bw")
    assert results.cpu_name(zen3 + zen4) == "AMD EPYC (family 25 model 1, AVX2)"  # the first processor
    assert results.cpu_name(zen4) == "AMD EPYC (family 25 model 17, AVX-512)"
    assert results.cpu_name("model name\t: Some CPU\n") == "Some CPU"  # nothing else known
    assert results.cpu_name("processor\t: 0\nflags\t: fpu\n") == ""  # no name: the caller's fallback


def test_commit_says_when_tracked_files_differ_from_head(tmp_path):
    def git(*a):
        subprocess.run(["git", *a], cwd=tmp_path, check=True, capture_output=True)

    git("init", "-q")
    (tmp_path / "f.txt").write_text("a\n")
    git("add", "f.txt")
    git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-q", "-m", "one")
    clean = results.commit(tmp_path)
    assert len(clean) == 12 and "uncommitted" not in clean
    (tmp_path / "new.txt").write_text("untracked files do not count\n")
    assert results.commit(tmp_path) == clean
    (tmp_path / "f.txt").write_text("b\n")
    assert results.commit(tmp_path) == clean + " + uncommitted changes"
    # a bench's own outputs (another bench's table written before it) are not changes to the code
    assert results.commit(tmp_path, outputs=("f.txt",)) == clean
    assert results.commit(tmp_path, outputs=("other.md", None)) == clean + " + uncommitted changes"
    outside = tmp_path.parent / "results_elsewhere.md"  # a results file outside the checkout
    assert results.commit(tmp_path, outputs=(str(outside), "f.txt")) == clean
    # run from a subfolder: the whole checkout still counts, outputs relative to that folder
    (tmp_path / "sub").mkdir()
    assert results.commit(tmp_path / "sub") == clean + " + uncommitted changes"
    assert results.commit(tmp_path / "sub", outputs=("../f.txt",)) == clean
