"""The tree tracks what users run and the records of results, not run artifacts: the tracked files total at most
60 MB and none is over 5 MB (results/runs/README.md says where training runs, demonstrations and buffers went)."""

import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MB = 1_000_000
TOTAL_LIMIT = 60 * MB
FILE_LIMIT = 5 * MB


def _tracked_sizes() -> dict[str, int]:
    """Size in bytes of every file ``git ls-files`` lists that exists in the working tree (a file deleted there but
    not yet from the index is on its way out)."""
    done = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=False)
    assert done.returncode == 0, (f"git ls-files failed in {ROOT} ({done.stderr.decode().strip()}); these tests run "
                                  f"in a git checkout of the repository")
    sizes = {}
    for name in done.stdout.decode().split("\0"):
        path = ROOT / name
        if name and path.is_file() and not path.is_symlink():
            sizes[name] = path.stat().st_size
    return sizes


def _largest(sizes: dict[str, int], count: int = 15) -> str:
    return "\n".join(f"  {size / MB:7.2f} MB  {name}" for name, size in
                     sorted(sizes.items(), key=lambda item: -item[1])[:count])


def test_no_tracked_file_is_over_5_mb():
    sizes = _tracked_sizes()
    assert sizes, "git ls-files lists no files"
    big = {name: size for name, size in sizes.items() if size > FILE_LIMIT}
    assert not big, (f"{len(big)} tracked file(s) over {FILE_LIMIT / MB:.0f} MB; keep run artifacts and large dumps "
                     f"out of the tree (a summary or curve in results/ instead):\n{_largest(big, len(big))}")


def test_the_tracked_files_total_at_most_60_mb():
    sizes = _tracked_sizes()
    total = sum(sizes.values())
    assert total <= TOTAL_LIMIT, (f"the tracked files total {total / MB:.1f} MB, over {TOTAL_LIMIT / MB:.0f} MB; the "
                                  f"largest:\n{_largest(sizes)}")
