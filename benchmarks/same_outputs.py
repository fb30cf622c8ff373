"""Do two runs of the DAG write the same outputs? Compares every JSON, HDF5 and CSV file under
results/ of two working directories (logs and benchmark files apart), wall times left out, and
prints JSON: the files compared, those only in one run, and every difference.

For a move of the code: run the same config at the old and the new commit, each in its own
folder, then compare them, e.g.

    git worktree add /tmp/old <old commit>
    (cd /tmp/old && snakemake --profile workflow/profiles/default --configfile config/tiny_all.yaml --cores 2)
    snakemake --profile workflow/profiles/default --configfile config/tiny_all.yaml --cores 2
    python benchmarks/same_outputs.py /tmp/old .

JSON: tests/test_same_answer.py's comparison (keys named as timings dropped at any depth).
HDF5: every dataset bit for bit and every file attribute but the timings. CSV: every column but
the timings, value for value.
"""

import argparse
import json
import sys
from pathlib import Path

import h5py
import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.test_same_answer import differences, is_timing, json_outputs  # noqa: E402


def other_files(workdir: Path, ext: str) -> set[str]:
    """Paths under results/ of the run's .<ext> files, logs and benchmark files apart."""
    results = workdir / "results"
    return {
        str(p.relative_to(results))
        for p in results.rglob(f"*.{ext}")
        if not str(p.relative_to(results)).startswith(("logs/", "benchmarks/"))
    }


def hdf5_differences(first: Path, second: Path) -> list[str]:
    out = []
    with h5py.File(first) as a, h5py.File(second) as b:
        names_a, names_b = set(), set()
        a.visititems(lambda name, obj: names_a.add(name) if isinstance(obj, h5py.Dataset) else None)
        b.visititems(lambda name, obj: names_b.add(name) if isinstance(obj, h5py.Dataset) else None)
        out += [f"{name}: only in one" for name in sorted(names_a ^ names_b)]
        same = {name for name in names_a & names_b if np.array_equal(a[name][()], b[name][()])}
        out += [f"{name}: differs" for name in sorted((names_a & names_b) - same)]
        for key in sorted(set(a.attrs) | set(b.attrs)):
            if not is_timing(key) and not np.array_equal(np.asarray(a.attrs.get(key)), np.asarray(b.attrs.get(key))):
                out.append(f"attribute {key}: {a.attrs.get(key)} != {b.attrs.get(key)}")
    return out


def csv_differences(first: Path, second: Path) -> list[str]:
    a, b = pd.read_csv(first), pd.read_csv(second)
    if list(a.columns) != list(b.columns) or len(a) != len(b):
        return [f"shape or columns: {a.shape} {list(a.columns)} != {b.shape} {list(b.columns)}"]
    return [f"column {c}" for c in a.columns if not is_timing(c) and not a[c].equals(b[c])]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("first", type=Path, help="working directory of one run (holding results/)")
    parser.add_argument("second", type=Path, help="working directory of the other")
    args = parser.parse_args()
    report = {"compared": 0, "only_in_one": [], "differ": {}}
    first_json, second_json = json_outputs(args.first), json_outputs(args.second)
    report["only_in_one"] += sorted(set(first_json) ^ set(second_json))
    for path in sorted(set(first_json) & set(second_json)):
        report["compared"] += 1
        if found := differences(first_json[path], second_json[path]):
            report["differ"][path] = found
    for ext, compare in (("h5", hdf5_differences), ("csv", csv_differences)):
        first, second = other_files(args.first, ext), other_files(args.second, ext)
        report["only_in_one"] += sorted(first ^ second)
        for path in sorted(first & second):
            report["compared"] += 1
            if found := compare(args.first / "results" / path, args.second / "results" / path):
                report["differ"][path] = found
    report["same"] = not report["differ"]
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
