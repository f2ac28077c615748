"""Nothing committed names an absolute path of a machine's own directories: the benchmark results, the package's
assets, the training configs, README.md and docs/ (scripts write paths through ``solaris_env.paths.portable_path``)."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# Absolute paths of a machine's own directories (a user's home, a scratch or work disk, the temporary folder).
ABSOLUTE = re.compile(r"(?<![\w.~$}/-])/(?:work|tmp|root|home|Users|mnt|scratch|private/var)/")


def committed_text_files() -> list[Path]:
    files = sorted((ROOT / "benchmarks" / "results").glob("*.json"))
    files += sorted(p for p in (ROOT / "solaris_env" / "assets").rglob("*") if p.suffix in (".json", ".md"))
    files += sorted((ROOT / "training" / "configs").glob("*.json"))
    return files + [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def test_no_committed_result_asset_or_doc_names_an_absolute_path():
    files = committed_text_files()
    assert ROOT / "README.md" in files and ROOT / "benchmarks" / "results" / "policy_eval_face_partner.json" in files
    found = []
    for path in files:
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            for match in ABSOLUTE.finditer(line):
                found.append(f"{path.relative_to(ROOT)}:{number}: ...{line[max(0, match.start() - 40):match.end() + 40]}...")
    assert not found, "absolute paths (write them through solaris_env.paths.portable_path):\n" + "\n".join(found)


def test_the_scan_catches_what_it_is_for():
    for text in ('"model": "/work/runs/all15/self-forcing/model"', "--data /home/me/data", "`/tmp/x`", "(/root/a)"):
        assert ABSOLUTE.search(text), text
    for text in ("runs/tmp/x", "http://host/home/page", "~/work/x", "$HOME/work", "/proc/self/clear_refs"):
        assert not ABSOLUTE.search(text), text
